// Packets: one encoded pass of one server frame, cut into datagrams of at most `max_payload`
// bytes, each with a fixed little-endian header that is checked before anything in it is used
// (docs/architecture.md, "Packets and the network"). Every packet repeats the pass description, so that any one packet
// lets the receiver check its limits before allocating anything.
//
// Header layout (kPacketHeaderBytes = 44, all integers little-endian):
//   offset size field
//        0    4 magic "DHRP"
//        4    1 version (kPacketVersion)
//        5    1 pass kind (PassKind)
//        6    2 stream id
//        8    4 frame id (the server frame)
//       12    4 codec id (codec_id(name): CRC-32C of the codec's registry name)
//       16    4 sequence number (per stream: packet i of a pass is first_sequence + i)
//       20    4 total encoded size of the pass, bytes
//       24    2 packet index (< count)
//       26    2 packet count (>= 1): the data packets; parity packets have indices count..
//                count + parity - 1 and payloads of the FEC shard size (core/net/fec.h)
//       28    2 chunk bytes: the payload of every packet but the last (1..65535)
//       30    2 payload bytes of this packet (= bytes after the header)
//       32    2 width       (32..37: the PassDesc the decoder needs)
//       34    2 height
//       36    1 channels
//       37    1 full_scale
//       38    2 parity packets of the pass (core/net/fec.h; 0: no forward error correction)
//       40    4 CRC-32C of bytes 0..39 followed by the payload
// A "stream" is (stream id, pass kind): sequence numbers count packets per stream (parity
// packets included), so that a gap in them is a lost packet of that stream.
#pragma once

#include "core/buffers/pass_buffer.h"

#include <cstddef>
#include <cstdint>
#include <span>
#include <string_view>
#include <vector>

namespace dhr {

constexpr uint8_t kPacketMagic[4] = {'D', 'H', 'R', 'P'};
constexpr uint8_t kPacketVersion = 1;
constexpr size_t kPacketHeaderBytes = 44;
// The default payload per packet: 1200 bytes keeps header + payload + IP/UDP well under the
// 1500-byte Ethernet MTU (and under the 1280-byte IPv6 minimum MTU with room for tunnels).
constexpr size_t kDefaultMaxPayloadBytes = 1200;
// The largest payload the header can describe that still fits one IPv4 UDP datagram
// (65535 - 20 IP - 8 UDP - header).
constexpr size_t kMaxPayloadLimitBytes = 65535 - 28 - kPacketHeaderBytes;
// IPv4 (20 bytes, no options) + UDP (8 bytes) headers, counted in every bandwidth figure.
constexpr size_t kIpUdpOverheadBytes = 28;

// CRC-32C of a codec's registry name: the codec id carried in the header.
uint32_t codec_id(std::string_view codec_name);

// What the sender knows about one encoded pass.
struct PacketMeta {
  uint16_t stream_id = 0;
  PassDesc desc;  // desc.kind is the pass
  uint32_t frame_id = 0;
  uint32_t codec_id = 0;
  uint32_t first_sequence = 0;  // sequence number of packet 0; the next pass starts at + count
  friend bool operator==(const PacketMeta&, const PacketMeta&) = default;
};

// How many packets packetize() makes for `encoded_bytes` (1 for an empty pass).
size_t packet_count(size_t encoded_bytes, size_t max_payload = kDefaultMaxPayloadBytes);

// Bytes one packet with `payload_bytes` of payload occupies on the wire: header + payload +
// IP/UDP headers.
constexpr size_t wire_bytes(size_t payload_bytes) { return kPacketHeaderBytes + payload_bytes + kIpUdpOverheadBytes; }
// Bytes all packets of a pass of `encoded_bytes` occupy on the wire.
size_t wire_bytes_of_pass(size_t encoded_bytes, size_t max_payload = kDefaultMaxPayloadBytes);
// Bytes on the wire of packets as sent (FEC parity packets included): each packet's size, the
// IP/UDP headers and `extra_per_packet` (live mode's MAC).
size_t wire_bytes_of_packets(const std::vector<std::vector<uint8_t>>& packets, size_t extra_per_packet = 0);

// Cuts `encoded` into datagrams of at most `max_payload` payload bytes (ready to send), then
// appends `parity` Reed-Solomon parity packets (core/net/fec.h; fec_parity_count gives a valid
// count; an empty pass gets none). Throws dhr::Error for a description that is invalid or does
// not fit the header, a max_payload outside 1..kMaxPayloadLimitBytes, a pass that needs more
// than 65535 packets or 4 GiB, or a parity count that forms no FEC layout.
std::vector<std::vector<uint8_t>> packetize(const PacketMeta& meta, std::span<const uint8_t> encoded,
                                            size_t max_payload = kDefaultMaxPayloadBytes, int parity = 0);
// The FEC shard size of a pass: its chunk, or its size when it has one packet.
size_t fec_shard_bytes(size_t total_bytes, size_t chunk_bytes);

enum class ParseResult : uint8_t {
  Ok = 0,
  TooShort,     // fewer bytes than a header
  BadMagic,     // not a dhrbench packet
  BadVersion,   // another version of the format
  BadChecksum,  // corrupted (or truncated: the checksum covers the payload)
  BadLength,    // payload bytes differ from the header, or disagree with total/count/chunk
  BadIndex,     // count == 0 or index >= count
  BadDesc,      // unknown pass kind or a description PassDesc::validate() refuses
  BadReserved,  // not produced: the header field it checked carries the parity count
};
constexpr int kParseResultCount = 9;
const char* parse_result_name(ParseResult r);

struct ParsedPacket {
  PacketMeta meta;  // first_sequence = this packet's sequence - index
  uint32_t sequence = 0;
  uint32_t total_bytes = 0;
  uint16_t index = 0;
  uint16_t count = 0;
  uint16_t chunk_bytes = 0;
  uint16_t parity = 0;               // parity packets of the pass (index >= count: this is one)
  std::span<const uint8_t> payload;  // points into the datagram given to parse_packet
  bool is_parity() const { return index >= count; }
  // Offset of this payload in the pass.
  size_t offset() const { return size_t(index) * chunk_bytes; }
};

// Checks a datagram in this order: length, magic, version, checksum, then the fields (the
// checksum comes before field checks so that a corrupted packet is counted as corrupted).
// On Ok, `out` holds the fields and every field has been checked: index < count + parity with
// parity forming a FEC layout (BadIndex otherwise; an empty pass has no parity), the payload
// length is the one total/count/chunk imply, the description is valid. On any other result
// `out` is unspecified. Never throws.
ParseResult parse_packet(std::span<const uint8_t> datagram, ParsedPacket& out);

// Recomputes the checksum of a datagram in place (for tests and fuzzers that craft headers;
// the datagram must be at least a header long).
void seal_packet(std::span<uint8_t> datagram);

}  // namespace dhr
