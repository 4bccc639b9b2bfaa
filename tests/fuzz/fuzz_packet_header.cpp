// libFuzzer target: parse_packet() and live mode's parse_control() on arbitrary datagrams. Each input is parsed as it is, then
// again with its checksum recomputed (a fuzzer cannot forge a CRC, so without this the field
// checks behind the checksum would never be reached). Properties checked on every accepted
// datagram: the fields are in range, and the datagram is byte for byte the one packetize()
// (encode_control()) makes for those fields, i.e. the parsers accept exactly the canonical
// encoding (data packets; a parity packet's payload depends on the whole pass).
#include "core/live/live_protocol.h"
#include "core/net/fec.h"
#include "core/net/packet.h"
#include "tests/fuzz/fuzz_common.h"

#include <algorithm>
#include <cstring>
#include <vector>

namespace {

void check_accepted(std::span<const uint8_t> d, const dhr::ParsedPacket& p) {
  using namespace dhr;
  DHR_FUZZ_CHECK(p.count >= 1 && size_t(p.index) < size_t(p.count) + p.parity);
  DHR_FUZZ_CHECK(p.chunk_bytes >= 1);
  DHR_FUZZ_CHECK(p.payload.data() == d.data() + kPacketHeaderBytes);
  DHR_FUZZ_CHECK(p.payload.size() == d.size() - kPacketHeaderBytes);
  DHR_FUZZ_CHECK(p.meta.desc.validate().empty());
  DHR_FUZZ_CHECK(p.sequence == p.meta.first_sequence + p.index);
  FecLayout fec;
  DHR_FUZZ_CHECK(fec_layout(p.count, p.parity, fec));
  if (p.is_parity()) {
    // A parity packet's payload is a function of the whole pass: only its size is checked.
    DHR_FUZZ_CHECK(p.total_bytes > 0 && p.payload.size() == fec_shard_bytes(p.total_bytes, p.chunk_bytes));
    return;
  }
  DHR_FUZZ_CHECK(p.offset() + p.payload.size() <= p.total_bytes);
  // Rebuild the pass around this payload and packetize it again (small passes only, to keep
  // the fuzzer fast; chunks above what packetize() accepts cannot be rebuilt).
  if (p.total_bytes > (1u << 16) || p.chunk_bytes > kMaxPayloadLimitBytes) return;
  std::vector<uint8_t> pass(p.total_bytes, 0);
  std::copy(p.payload.begin(), p.payload.end(), pass.begin() + std::ptrdiff_t(p.offset()));
  const auto again = packetize(p.meta, pass, p.chunk_bytes, p.parity);  // must not throw
  DHR_FUZZ_CHECK(again.size() == size_t(p.count) + p.parity);
  const auto& mine = again[p.index];
  DHR_FUZZ_CHECK(mine.size() == d.size() && std::memcmp(mine.data(), d.data(), d.size()) == 0);
}

void check_control(std::span<const uint8_t> d) {
  using namespace dhr;
  ControlMessage m;
  if (parse_control(d, m) != ControlParse::Ok) return;
  const std::vector<uint8_t> again = encode_control(m);  // must not throw
  DHR_FUZZ_CHECK(again.size() == d.size() && std::memcmp(again.data(), d.data(), d.size()) == 0);
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace dhr;
  const std::span<const uint8_t> d(data, size);
  ParsedPacket p;
  if (parse_packet(d, p) == ParseResult::Ok) check_accepted(d, p);

  if (size >= kPacketHeaderBytes) {
    std::vector<uint8_t> sealed(data, data + size);
    seal_packet(sealed);
    ParsedPacket q;
    const ParseResult r = parse_packet(sealed, q);
    DHR_FUZZ_CHECK(r != ParseResult::BadChecksum && r != ParseResult::TooShort);
    if (r == ParseResult::Ok) check_accepted(sealed, q);
  }
  check_control(d);
  if (size >= kControlHeaderBytes) {
    std::vector<uint8_t> sealed(data, data + size);
    std::memcpy(sealed.data(), kControlMagic, 4);  // reach the checks behind the magic
    seal_control(sealed);
    ControlMessage m;
    DHR_FUZZ_CHECK(parse_control(sealed, m) != ControlParse::BadChecksum);
    check_control(sealed);
  }
  return 0;
}
