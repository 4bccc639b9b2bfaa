#include "core/net/packet.h"

#include "core/base/byte_order.h"
#include "core/base/checksum.h"
#include "core/base/error.h"
#include "core/net/fec.h"

#include <algorithm>
#include <cstring>

namespace dhr {
namespace {

using le::get16;
using le::get32;
using le::put16;
using le::put32;

// Offsets of the header fields (see the table in packet.h).
constexpr size_t kOffVersion = 4, kOffPass = 5, kOffStream = 6, kOffFrame = 8, kOffCodec = 12, kOffSequence = 16,
                 kOffTotal = 20, kOffIndex = 24, kOffCount = 26, kOffChunk = 28, kOffPayloadLen = 30, kOffWidth = 32,
                 kOffHeight = 34, kOffChannels = 36, kOffFullScale = 37, kOffParity = 38, kOffChecksum = 40;
static_assert(kOffChecksum + 4 == kPacketHeaderBytes);

// The checksum covers the header up to the checksum field, then everything after the header
// (whatever its length field claims), so truncation and extension are both caught.
uint32_t datagram_checksum(std::span<const uint8_t> d) {
  const uint32_t c = crc32c(d.first(kOffChecksum));
  return crc32c(d.subspan(kPacketHeaderBytes), c);
}

uint64_t count_for(uint64_t total, uint64_t chunk) { return total == 0 ? 1 : (total + chunk - 1) / chunk; }

bool known_pass(uint8_t kind) { return find_pass_kind(kind) != nullptr; }

}  // namespace

uint32_t codec_id(std::string_view codec_name) {
  return crc32c({reinterpret_cast<const uint8_t*>(codec_name.data()), codec_name.size()});
}

size_t packet_count(size_t encoded_bytes, size_t max_payload) {
  if (max_payload == 0) fail("packet_count: max_payload must be at least 1 byte");
  return size_t(count_for(encoded_bytes, max_payload));
}

size_t wire_bytes_of_pass(size_t encoded_bytes, size_t max_payload) {
  return encoded_bytes + packet_count(encoded_bytes, max_payload) * wire_bytes(0);
}

size_t wire_bytes_of_packets(const std::vector<std::vector<uint8_t>>& packets, size_t extra_per_packet) {
  size_t wire = 0;
  for (const auto& packet : packets) wire += packet.size() + kIpUdpOverheadBytes + extra_per_packet;
  return wire;
}

size_t fec_shard_bytes(size_t total_bytes, size_t chunk_bytes) {
  return total_bytes <= chunk_bytes ? total_bytes : chunk_bytes;
}

std::vector<std::vector<uint8_t>> packetize(const PacketMeta& meta, std::span<const uint8_t> encoded,
                                            size_t max_payload, int parity) {
  if (max_payload < 1 || max_payload > kMaxPayloadLimitBytes)
    fail("packetize: max_payload {} out of range 1..{}", max_payload, kMaxPayloadLimitBytes);
  const PassDesc& d = meta.desc;
  if (std::string why = d.validate(); !why.empty())
    fail("packetize: stream {} frame {}: invalid pass description: {}", meta.stream_id, meta.frame_id, why);
  // validate() bounds width/height by kMaxImageSide (16384) and channels by 64, so they fit
  // the header's 16- and 8-bit fields; full_scale is only bounded for Ao/SoftVisibility.
  if (d.full_scale < 0 || d.full_scale > 255)
    fail("packetize: full_scale {} does not fit the header (0..255)", d.full_scale);
  if (encoded.size() > UINT32_MAX)
    fail("packetize: a pass of {} bytes is above the 4 GiB a header can describe", encoded.size());
  const size_t count = packet_count(encoded.size(), max_payload);
  if (count > UINT16_MAX)
    fail("packetize: {} bytes need {} packets of {} bytes, above 65535: raise max_payload", encoded.size(), count,
         max_payload);

  if (encoded.empty()) parity = 0;
  FecLayout fec;
  if (!fec_layout(int(count), parity, fec))
    fail("packetize: {} parity packets for {} data packets form no FEC layout (core/net/fec.h)", parity, count);
  const size_t shard = fec_shard_bytes(encoded.size(), max_payload);

  std::vector<std::vector<uint8_t>> packets(count + size_t(parity));
  for (size_t i = 0; i < packets.size(); ++i) {
    const size_t offset = i * max_payload;
    const size_t len = i < count ? std::min(max_payload, encoded.size() - offset) : shard;
    auto& p = packets[i];
    p.assign(kPacketHeaderBytes + len, 0);
    uint8_t* h = p.data();
    std::memcpy(h, kPacketMagic, 4);
    h[kOffVersion] = kPacketVersion;
    h[kOffPass] = uint8_t(d.kind);
    put16(h + kOffStream, meta.stream_id);
    put32(h + kOffFrame, meta.frame_id);
    put32(h + kOffCodec, meta.codec_id);
    put32(h + kOffSequence, uint32_t(meta.first_sequence + i));  // wraps modulo 2^32 by design
    put32(h + kOffTotal, uint32_t(encoded.size()));
    put16(h + kOffIndex, uint32_t(i));
    put16(h + kOffCount, uint32_t(count));
    put16(h + kOffChunk, uint32_t(max_payload));
    put16(h + kOffPayloadLen, uint32_t(len));
    put16(h + kOffWidth, uint32_t(d.width));
    put16(h + kOffHeight, uint32_t(d.height));
    h[kOffChannels] = uint8_t(d.channels);
    h[kOffFullScale] = uint8_t(d.full_scale);
    put16(h + kOffParity, uint32_t(parity));
    if (i < count && len) std::memcpy(h + kPacketHeaderBytes, encoded.data() + offset, len);
  }
  if (parity > 0) {
    // Each block's data shards (the last one zero-padded to the shard size) and parity shards.
    std::vector<uint8_t> last(shard, 0);
    const size_t tail = encoded.size() - (count - 1) * max_payload;
    std::memcpy(last.data(), encoded.data() + (count - 1) * max_payload, tail);
    for (int b = 0; b < fec.blocks; ++b) {
      std::vector<const uint8_t*> data;
      std::vector<uint8_t*> out;
      for (size_t i = size_t(b); i < count; i += size_t(fec.blocks))
        data.push_back(i + 1 == count ? last.data() : encoded.data() + i * max_payload);
      for (int j = 0; j < fec.per_block; ++j)
        out.push_back(packets[count + size_t(b * fec.per_block + j)].data() + kPacketHeaderBytes);
      rs_encode(int(data.size()), fec.per_block, shard, data.data(), out.data());
    }
  }
  for (auto& p : packets) put32(p.data() + kOffChecksum, datagram_checksum(p));
  return packets;
}

void seal_packet(std::span<uint8_t> datagram) {
  if (datagram.size() < kPacketHeaderBytes)
    fail("seal_packet: {} bytes is shorter than a {}-byte header", datagram.size(), kPacketHeaderBytes);
  put32(datagram.data() + kOffChecksum, datagram_checksum(datagram));
}

ParseResult parse_packet(std::span<const uint8_t> d, ParsedPacket& out) {
  if (d.size() < kPacketHeaderBytes) return ParseResult::TooShort;
  const uint8_t* h = d.data();
  if (std::memcmp(h, kPacketMagic, 4) != 0) return ParseResult::BadMagic;
  if (h[kOffVersion] != kPacketVersion) return ParseResult::BadVersion;
  if (get32(h + kOffChecksum) != datagram_checksum(d)) return ParseResult::BadChecksum;

  out.total_bytes = get32(h + kOffTotal);
  out.index = get16(h + kOffIndex);
  out.count = get16(h + kOffCount);
  out.chunk_bytes = get16(h + kOffChunk);
  out.parity = get16(h + kOffParity);
  const uint16_t payload_len = get16(h + kOffPayloadLen);
  FecLayout fec;
  if (out.count == 0 || !fec_layout(out.count, out.parity, fec) ||
      size_t(out.index) >= size_t(out.count) + out.parity || (out.parity > 0 && out.total_bytes == 0))
    return ParseResult::BadIndex;
  if (out.chunk_bytes == 0) return ParseResult::BadLength;
  if (payload_len != d.size() - kPacketHeaderBytes) return ParseResult::BadLength;
  // The sender cuts a pass into chunks of chunk_bytes, the last one shorter: so count and
  // each payload length follow from total and chunk (parity packets: the FEC shard size).
  if (count_for(out.total_bytes, out.chunk_bytes) != out.count) return ParseResult::BadLength;
  const uint64_t expected_len = out.index >= out.count ? fec_shard_bytes(out.total_bytes, out.chunk_bytes)
                                : out.index + 1 < out.count
                                    ? uint64_t(out.chunk_bytes)
                                    : out.total_bytes - uint64_t(out.count - 1) * out.chunk_bytes;
  if (payload_len != expected_len) return ParseResult::BadLength;

  if (!known_pass(h[kOffPass])) return ParseResult::BadDesc;
  PassDesc& desc = out.meta.desc;
  desc.kind = PassKind(h[kOffPass]);
  desc.width = get16(h + kOffWidth);
  desc.height = get16(h + kOffHeight);
  desc.channels = h[kOffChannels];
  desc.full_scale = h[kOffFullScale];
  if (!desc.validate().empty()) return ParseResult::BadDesc;

  out.meta.stream_id = get16(h + kOffStream);
  out.meta.frame_id = get32(h + kOffFrame);
  out.meta.codec_id = get32(h + kOffCodec);
  out.sequence = get32(h + kOffSequence);
  out.meta.first_sequence = out.sequence - out.index;
  out.payload = d.subspan(kPacketHeaderBytes);
  return ParseResult::Ok;
}

const char* parse_result_name(ParseResult r) {
  switch (r) {
    case ParseResult::Ok: return "ok";
    case ParseResult::TooShort: return "too_short";
    case ParseResult::BadMagic: return "bad_magic";
    case ParseResult::BadVersion: return "bad_version";
    case ParseResult::BadChecksum: return "bad_checksum";
    case ParseResult::BadLength: return "bad_length";
    case ParseResult::BadIndex: return "bad_index";
    case ParseResult::BadDesc: return "bad_desc";
    case ParseResult::BadReserved: return "bad_reserved";
  }
  return "unknown";
}

}  // namespace dhr
