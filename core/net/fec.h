// Forward error correction of a pass's packets: a systematic Reed-Solomon erasure code over
// GF(2^8) (Intel ISA-L's Cauchy matrix), so that the receiver rebuilds a frame from any k of
// its k data packets plus m parity packets (docs/architecture.md, "Packets and the network").
//
// Layout of one pass with `data` packets and `parity` parity packets (core/net/packet.h carries
// `parity` in every header; the rest follows from it):
// - The data packets are split into `blocks` = ceil(data / kFecMaxBlockData) interleaved blocks:
//   data packet i belongs to block i % blocks (so a burst of losses spreads over the blocks).
//   Each block has the same number m = parity / blocks of parity packets (parity is a multiple
//   of blocks), and data + parity of a block is at most kFecMaxShards.
// - Every shard is `shard_bytes` long: the chunk size, or the pass's size when it has one packet;
//   the last data packet is read as zero-padded to it.
// - Parity packet index data + b * m + j is parity shard j of block b.
// A block rebuilds when at least as many of its shards arrived as it has data packets.
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

namespace dhr {

constexpr int kFecMaxShards = 255;     // data + parity shards of one block (GF(2^8))
constexpr int kFecMaxBlockData = 128;  // data packets of one block; more: more blocks

struct FecLayout {
  int data = 0;    // data packets of the pass
  int parity = 0;  // parity packets of the pass (blocks * per_block)
  int blocks = 1;
  int per_block = 0;  // parity packets per block
  // Data packets of block b.
  int block_data(int b) const { return (data - b + blocks - 1) / blocks; }
  // The block of packet `index` (data or parity).
  int block_of(int index) const { return index < data ? index % blocks : (index - data) / per_block; }
};

// The layout of `data` data packets with `parity` parity packets; false when they do not form
// one (parity not a multiple of the blocks, a block above kFecMaxShards, data < 1, or more than
// 65535 packets in all). parity = 0 is always valid.
bool fec_layout(int data, int parity, FecLayout& out);

// The parity packets a sender adds: per block max(min_parity, ceil(fraction * block data)),
// capped so that a block stays within kFecMaxShards; 0 when both are 0. Throws dhr::Error for a
// fraction outside 0..1 or min_parity outside 0..kFecMaxShards - 1.
int fec_parity_count(int data, double fraction, int min_parity);

// True when every block holds at least as many packets (data or parity) as it has data packets:
// then every data packet is there or can be rebuilt. `block_have` holds the count per block.
bool fec_blocks_complete(const FecLayout& layout, std::span<const uint16_t> block_have);
// The same for the packets marked in `arrived` (data + parity entries, in index order).
bool fec_can_rebuild(const FecLayout& layout, const std::vector<bool>& arrived);

// Parity of one block: `k` data shards and `m` parity shards of `len` bytes each.
void rs_encode(int k, int m, size_t len, const uint8_t* const* data, uint8_t* const* parity);

// Rebuilds the missing data shards of one block from `k` present shards. `present` lists the
// shard numbers (0..k-1 data, k..k+m-1 parity) of the shards in `shards`, k of them, distinct;
// `missing` lists the data shard numbers to rebuild into `out` (same order); as many parity
// shards as missing data shards must be among the present ones. False when the shard numbers
// are invalid or repeated.
bool rs_decode(int k, int m, size_t len, std::span<const int> present, const uint8_t* const* shards,
               std::span<const int> missing, uint8_t* const* out);

}  // namespace dhr
