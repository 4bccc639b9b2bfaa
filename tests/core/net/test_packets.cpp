// Packets and the assembler: checksums, header checks, corruption and truncation, limits before
// allocation, reordering, duplicates, timeouts, loss counted from sequence numbers, and
// frames rebuilt by forward error correction.
#include "core/base/checksum.h"
#include "core/base/error.h"
#include "core/base/rng.h"
#include "core/net/assembler.h"
#include "core/net/fec.h"
#include "core/net/packet.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cstring>
#include <bit>
#include <map>
#include <optional>
#include <set>
#include <string>

namespace dhr {
namespace {

std::span<const uint8_t> bytes_of(const std::string& s) {
  return {reinterpret_cast<const uint8_t*>(s.data()), s.size()};
}

std::vector<uint8_t> random_bytes(size_t n, uint64_t seed, uint32_t frame = 0) {
  std::vector<uint8_t> v(n);
  for (size_t i = 0; i < n; ++i) v[i] = uint8_t(rng_bits({seed, uint32_t(i), frame, 0, kStreamNetwork}));
  return v;
}

template <class T>
void shuffle(std::vector<T>& v, uint64_t seed) {
  for (size_t i = v.size(); i > 1; --i) {
    const size_t j = size_t(rng_bits({seed, uint32_t(i), 0, 0, kStreamNetwork}) % i);
    std::swap(v[i - 1], v[j]);
  }
}

PacketMeta make_meta(uint32_t frame, uint16_t stream = 3, uint32_t first_sequence = 0) {
  PacketMeta m;
  m.stream_id = stream;
  m.desc = {PassKind::Ao, 64, 48, 1, 16};
  m.frame_id = frame;
  m.codec_id = codec_id("raw");
  m.first_sequence = first_sequence;
  return m;
}

// Little-endian field editors for crafting headers (offsets from the table in packet.h).
void put16(std::vector<uint8_t>& d, size_t off, uint32_t v) {
  d[off] = uint8_t(v);
  d[off + 1] = uint8_t(v >> 8);
}
void put32(std::vector<uint8_t>& d, size_t off, uint32_t v) {
  for (int i = 0; i < 4; ++i) d[off + size_t(i)] = uint8_t(v >> (8 * i));
}

ParseResult parse(const std::vector<uint8_t>& d) {
  ParsedPacket p;
  return parse_packet(d, p);
}

// ---- Checksum

TEST(Crc32c, KnownVectors) {
  EXPECT_EQ(crc32c(bytes_of("123456789")), 0xE3069283u);
  EXPECT_EQ(crc32c_portable(bytes_of("123456789")), 0xE3069283u);
  EXPECT_EQ(crc32c({}), 0u);
  // RFC 3720 appendix B.4.
  std::vector<uint8_t> zeros(32, 0), ones(32, 0xFF), up(32);
  for (int i = 0; i < 32; ++i) up[size_t(i)] = uint8_t(i);
  EXPECT_EQ(crc32c(zeros), 0x8A9136AAu);
  EXPECT_EQ(crc32c(ones), 0x62A8AB43u);
  EXPECT_EQ(crc32c(up), 0x46DD794Eu);
  EXPECT_EQ(crc32c_portable(up), 0x46DD794Eu);
}

TEST(Crc32c, HardwareMatchesPortableAndPiecesCompose) {
  const auto data = random_bytes(4099, 7);
  const std::span<const uint8_t> all(data);
  for (size_t start = 0; start < 9; ++start)
    for (size_t len : {size_t(0), size_t(1), size_t(7), size_t(8), size_t(9), size_t(63), size_t(4090)}) {
      const auto s = all.subspan(start, len);
      EXPECT_EQ(crc32c(s), crc32c_portable(s)) << start << " " << len;
    }
  for (size_t cut : {size_t(0), size_t(1), size_t(5), size_t(8), size_t(1000), data.size()}) {
    EXPECT_EQ(crc32c(all.subspan(cut), crc32c(all.first(cut))), crc32c(all));
    EXPECT_EQ(crc32c_portable(all.subspan(cut), crc32c_portable(all.first(cut))), crc32c(all));
  }
}

// ---- Packet format

TEST(Packet, HeaderLayoutAndWireSize) {
  const auto payload = random_bytes(1500, 1);
  auto m = make_meta(0x01020304, 0x0A0B, 100);
  const auto pk = packetize(m, payload, 1000);
  ASSERT_EQ(pk.size(), 2u);
  EXPECT_EQ(pk[0].size(), kPacketHeaderBytes + 1000);
  EXPECT_EQ(pk[1].size(), kPacketHeaderBytes + 500);
  EXPECT_EQ(std::memcmp(pk[0].data(), "DHRP", 4), 0);
  EXPECT_EQ(pk[0][4], kPacketVersion);
  EXPECT_EQ(pk[0][5], uint8_t(PassKind::Ao));
  EXPECT_EQ(pk[0][6], 0x0B);  // little-endian stream id
  EXPECT_EQ(pk[0][8], 0x04);  // little-endian frame id
  EXPECT_EQ(pk[0][11], 0x01);
  EXPECT_EQ(pk[1][16], 101);  // sequence number of packet 1
  EXPECT_EQ(std::memcmp(pk[1].data() + kPacketHeaderBytes, payload.data() + 1000, 500), 0);

  ParsedPacket p;
  ASSERT_EQ(parse_packet(pk[1], p), ParseResult::Ok);
  EXPECT_EQ(p.meta, m);  // first_sequence is recovered from sequence - index
  EXPECT_EQ(p.sequence, 101u);
  EXPECT_EQ(p.index, 1);
  EXPECT_EQ(p.count, 2);
  EXPECT_EQ(p.total_bytes, 1500u);
  EXPECT_EQ(p.offset(), 1000u);
  EXPECT_EQ(p.payload.size(), 500u);

  EXPECT_EQ(kIpUdpOverheadBytes, 28u);
  EXPECT_EQ(wire_bytes(1200), 1200 + kPacketHeaderBytes + 28);
  EXPECT_EQ(wire_bytes_of_pass(1500, 1000), 1500 + 2 * (kPacketHeaderBytes + 28));
  EXPECT_EQ(wire_bytes_of_pass(0), kPacketHeaderBytes + 28);  // an empty pass is one packet
  size_t sum = 0;
  for (const auto& d : pk) sum += d.size() + kIpUdpOverheadBytes;
  EXPECT_EQ(sum, wire_bytes_of_pass(1500, 1000));
  EXPECT_EQ(codec_id("raw"), crc32c(bytes_of("raw")));
  EXPECT_NE(codec_id("lz4"), codec_id("zstd"));
}

TEST(Packet, PacketizeRefusesWhatTheHeaderCannotCarry) {
  const std::vector<uint8_t> data(10);
  EXPECT_THROW(packetize(make_meta(0), data, 0), Error);
  EXPECT_THROW(packetize(make_meta(0), data, kMaxPayloadLimitBytes + 1), Error);
  auto bad = make_meta(0);
  bad.desc.channels = 2;  // ao has one channel
  EXPECT_THROW(packetize(bad, data), Error);
  bad = make_meta(0);
  bad.desc = {PassKind::Colour, 8, 8, 3, 1000};
  EXPECT_THROW(packetize(bad, data), Error);
  // 70000 bytes in 1-byte packets would need more than 65535 packets.
  EXPECT_THROW(packetize(make_meta(0), std::vector<uint8_t>(70000), 1), Error);
  EXPECT_NO_THROW(packetize(make_meta(0), std::vector<uint8_t>(65535), 1));
}

TEST(Packet, FieldChecksOnSealedHeaders) {
  const auto good = packetize(make_meta(5), random_bytes(2500, 2), 1000);  // 1000, 1000, 500
  auto edit = [&](size_t i, auto&& change) {
    auto d = good[i];
    change(d);
    seal_packet(d);
    return parse(d);
  };
  EXPECT_EQ(parse(good[2]), ParseResult::Ok);
  EXPECT_EQ(edit(0, [](auto& d) { d[0] = 'X'; }), ParseResult::BadMagic);
  EXPECT_EQ(edit(0, [](auto& d) { d[4] = kPacketVersion + 1; }), ParseResult::BadVersion);
  EXPECT_EQ(edit(0, [](auto& d) { put16(d, 38, 253); }), ParseResult::BadIndex);    // 3 + 253 shards > 255
  EXPECT_EQ(edit(0, [](auto& d) { put16(d, 24, 3); }), ParseResult::BadIndex);      // index == count
  EXPECT_EQ(edit(0, [](auto& d) { put16(d, 26, 0); }), ParseResult::BadIndex);      // count 0
  EXPECT_EQ(edit(0, [](auto& d) { put16(d, 26, 4); }), ParseResult::BadLength);     // count != ceil(total/chunk)
  EXPECT_EQ(edit(0, [](auto& d) { put32(d, 20, 3100); }), ParseResult::BadLength);  // total
  EXPECT_EQ(edit(0, [](auto& d) { put16(d, 28, 0); }), ParseResult::BadLength);     // chunk 0
  EXPECT_EQ(edit(0, [](auto& d) { put16(d, 30, 999); }), ParseResult::BadLength);   // length field
  EXPECT_EQ(edit(2, [](auto& d) { d.pop_back(); }), ParseResult::BadLength);        // sealed but short
  EXPECT_EQ(edit(1, [](auto& d) { put16(d, 24, 2); }), ParseResult::BadLength);     // last would be 500
  EXPECT_EQ(edit(0, [](auto& d) { d[5] = 0; }), ParseResult::BadDesc);              // pass kind
  EXPECT_EQ(edit(0, [](auto& d) { d[5] = 9; }), ParseResult::BadDesc);
  EXPECT_EQ(edit(0, [](auto& d) { put16(d, 32, 20000); }), ParseResult::BadDesc);  // width
  EXPECT_EQ(edit(0, [](auto& d) { d[36] = 2; }), ParseResult::BadDesc);            // ao channels
  EXPECT_EQ(edit(0, [](auto& d) { d[37] = 0; }), ParseResult::BadDesc);            // full_scale
  std::vector<uint8_t> header_only(good[0].begin(), good[0].begin() + kPacketHeaderBytes);
  EXPECT_EQ(parse(header_only), ParseResult::BadChecksum);
  EXPECT_THROW(seal_packet(std::span<uint8_t>(header_only).first(10)), Error);
}

TEST(Packet, EverySingleBitFlipIsCaught) {
  const auto payload = random_bytes(3000, 3);
  const auto meta = make_meta(9);
  const auto pk = packetize(meta, payload, 1200);
  Assembler a;
  uint64_t flips = 0;
  for (const auto& original : pk) {
    for (size_t bit = 0; bit < original.size() * 8; ++bit) {
      auto d = original;
      d[bit / 8] ^= uint8_t(1u << (bit % 8));
      ASSERT_NE(parse(d), ParseResult::Ok) << "bit " << bit;
      const PacketFate f = a.push(d, 0);
      ASSERT_TRUE(f == PacketFate::BadChecksum || f == PacketFate::BadMagic || f == PacketFate::BadVersion)
          << packet_fate_name(f);
      ++flips;
    }
  }
  EXPECT_EQ(a.stats().packets_dropped(), flips);
  EXPECT_EQ(a.stats().frames_in_flight, 0u);
  // The intact packets still assemble to the right bytes.
  for (const auto& d : pk) a.push(d, 0);
  auto ev = a.poll(0);
  ASSERT_EQ(ev.completed.size(), 1u);
  EXPECT_EQ(ev.completed[0].encoded, payload);
}

TEST(Packet, TruncationAtEveryLengthAndExtensionAreCaught) {
  const auto pk = packetize(make_meta(1), random_bytes(1700, 4), 1200);
  for (const auto& original : pk) {
    for (size_t len = 0; len < original.size(); ++len) {
      std::vector<uint8_t> d(original.begin(), original.begin() + std::ptrdiff_t(len));
      const ParseResult r = parse(d);
      ASSERT_EQ(r, len < kPacketHeaderBytes ? ParseResult::TooShort : ParseResult::BadChecksum) << len;
    }
    auto longer = original;
    longer.push_back(0);
    EXPECT_EQ(parse(longer), ParseResult::BadChecksum);
  }
}

TEST(Packet, ForeignDatagramsAreDropped) {
  Assembler a;
  uint64_t n = 0;
  for (uint32_t i = 0; i < 5000; ++i) {
    const size_t len = size_t(rng_bits({11, i, 0, 0, kStreamNetwork}) % 1400);
    auto d = random_bytes(len, 100 + i);
    if (i % 2 && len >= 4) std::memcpy(d.data(), kPacketMagic, 4);  // right magic, garbage after
    if (i % 4 == 1 && len > 4) d[4] = kPacketVersion;
    EXPECT_NE(parse(d), ParseResult::Ok);
    EXPECT_GE(int(a.push(d, i)), int(PacketFate::TooShort));
    ++n;
  }
  EXPECT_EQ(a.stats().packets_dropped(), n);
  EXPECT_EQ(a.stats().peak_frames_in_flight, 0u);
  EXPECT_EQ(a.streams(), 0u);
  // Another protocol's magic with an otherwise perfect packet.
  auto d = packetize(make_meta(0), random_bytes(10, 5))[0];
  std::memcpy(d.data(), "RTP2", 4);
  seal_packet(d);
  EXPECT_EQ(a.push(d, 0), PacketFate::BadMagic);
}

// ---- Assembler

TEST(Assembler, RoundTripShuffledWithDuplicates) {
  for (size_t size : {size_t(0), size_t(1), size_t(1199), size_t(1200), size_t(1201), size_t(1) << 20}) {
    const auto payload = random_bytes(size, 20 + size);
    const auto meta = make_meta(7, 2, 1000);
    auto pk = packetize(meta, payload);
    ASSERT_EQ(pk.size(), packet_count(size));
    const size_t distinct = pk.size();
    // Duplicate every third packet (and the first), then shuffle.
    for (size_t i = 0; i < distinct; i += 3) pk.push_back(pk[i]);
    shuffle(pk, size);
    Assembler a;
    size_t completed = 0;
    for (const auto& d : pk) {
      const PacketFate f = a.push(d, 5);
      completed += f == PacketFate::Completed;
      ASSERT_TRUE(f == PacketFate::Accepted || f == PacketFate::Completed || f == PacketFate::Duplicate ||
                  f == PacketFate::FinishedFrame)
          << packet_fate_name(f);
    }
    EXPECT_EQ(completed, 1u);
    const auto ev = a.poll(5);
    ASSERT_EQ(ev.completed.size(), 1u) << size;
    EXPECT_TRUE(ev.lost.empty());
    EXPECT_EQ(ev.completed[0].meta, meta);
    EXPECT_EQ(ev.completed[0].encoded, payload);
    EXPECT_EQ(ev.completed[0].packet_count, distinct);
    EXPECT_FALSE(ev.completed[0].late);
    // Every duplicate is dropped: as a duplicate, or as a packet of a finished frame.
    EXPECT_EQ(a.stats().count(PacketFate::Duplicate), pk.size() - distinct);
    EXPECT_EQ(a.stats().frames_in_flight, 0u);
    EXPECT_EQ(a.stats().bytes_in_flight, 0u);
    EXPECT_EQ(a.stats().packets_lost, 0u);
    EXPECT_EQ(a.packets_missing(), 0u);
  }
}

TEST(Assembler, ReorderingAcrossFramesAndStreams) {
  // Three streams (two passes of stream 1, one of stream 2), six frames each, all packets
  // interleaved at random. With late delivery on, every frame completes with its own bytes.
  for (bool late_ok : {true, false}) {
    std::map<std::tuple<uint16_t, int, uint32_t>, std::vector<uint8_t>> sent;
    std::vector<std::vector<uint8_t>> all;
    std::map<std::pair<uint16_t, int>, uint32_t> seq;
    for (uint32_t frame = 0; frame < 6; ++frame)
      for (auto [stream, kind] :
           {std::pair<uint16_t, PassKind>{1, PassKind::Ao}, {1, PassKind::Colour}, {2, PassKind::Ao}}) {
        PacketMeta m = make_meta(frame, stream);
        if (kind == PassKind::Colour) m.desc = {PassKind::Colour, 32, 32, 3, 255};
        uint32_t& next = seq[{stream, int(kind)}];
        m.first_sequence = next;
        auto payload = random_bytes(500 + 700 * frame, stream * 10 + uint32_t(kind), frame);
        auto pk = packetize(m, payload, 400);
        next += uint32_t(pk.size());
        for (auto& d : pk) all.push_back(std::move(d));
        sent[{stream, int(kind), frame}] = std::move(payload);
      }
    shuffle(all, 77);
    AssemblerConfig cfg;
    cfg.deliver_late_frames = late_ok;
    Assembler a(cfg);
    for (const auto& d : all) a.push(d, 0);
    const auto ev = a.poll(0);
    std::map<std::pair<uint16_t, int>, int64_t> last_delivered;
    for (const auto& f : ev.completed) {
      EXPECT_EQ(f.encoded, (sent[{f.meta.stream_id, int(f.meta.desc.kind), f.meta.frame_id}]));
      auto key = std::pair<uint16_t, int>{f.meta.stream_id, int(f.meta.desc.kind)};
      if (!late_ok) {
        EXPECT_FALSE(f.late);
        EXPECT_GT(int64_t(f.meta.frame_id), last_delivered.count(key) ? last_delivered[key] : -1);
      }
      last_delivered[key] = f.meta.frame_id;
    }
    for (const auto& l : ev.lost) EXPECT_EQ(l.reason, LossReason::Superseded);
    EXPECT_EQ(ev.completed.size() + ev.lost.size(), sent.size());
    if (late_ok) {
      EXPECT_EQ(ev.completed.size(), sent.size());
      EXPECT_TRUE(ev.lost.empty());
    }
    EXPECT_EQ(a.stats().packets_lost, 0u);
    EXPECT_EQ(a.packets_missing(), 0u);
    EXPECT_EQ(a.stats().frames_in_flight, 0u);
  }
}

TEST(Assembler, InFlightLimitKeepsMemoryBounded) {
  AssemblerConfig cfg;
  cfg.max_frames_in_flight = 8;
  Assembler a(cfg);
  const auto payload = random_bytes(3000, 1);
  uint32_t seq = 0;
  size_t reported = 0;
  for (uint32_t frame = 0; frame < 10000; ++frame) {
    auto pk = packetize(make_meta(frame, 1, seq), payload);
    seq += uint32_t(pk.size());
    a.push(pk[0], frame);  // only the first packet of each frame ever arrives
    ASSERT_LE(a.stats().frames_in_flight, 8u);
    ASSERT_LE(a.stats().bytes_in_flight, 8u * 3000);
    if (frame % 1000 == 999) reported += a.poll(frame).lost.size();
  }
  EXPECT_EQ(a.stats().peak_frames_in_flight, 8u);
  EXPECT_LE(a.stats().peak_bytes_in_flight, 8u * 3000);
  EXPECT_EQ(a.stats().lost(LossReason::Evicted), 10000u - 8);
  EXPECT_EQ(reported, 10000u - 8);
  EXPECT_EQ(a.stats().lost_reports_dropped, 0u);
  // The oldest frame is the one given up: a packet of an evicted frame is refused.
  auto pk0 = packetize(make_meta(0, 1, 0), payload);
  EXPECT_EQ(a.push(pk0[1], 10000), PacketFate::Evicted);
}

TEST(Assembler, QueuesAreBoundedWhenNobodyPolls) {
  AssemblerConfig cfg;
  cfg.max_streams = 1;
  cfg.max_frames_in_flight = 2;
  Assembler a(cfg);
  const auto payload = random_bytes(1500, 1);
  for (uint32_t frame = 0; frame < 5000; ++frame) {
    const auto pk = packetize(make_meta(frame, 1, 2 * frame), payload);
    a.push(pk[0], frame);
    if (frame % 2) a.push(pk[1], frame);  // odd frames complete, even ones are superseded
  }
  const auto ev = a.poll(5000);
  EXPECT_EQ(ev.completed.size(), 2u);  // max_streams x max_frames_in_flight
  EXPECT_LE(ev.lost.size(), 4096u);
  EXPECT_EQ(a.stats().lost(LossReason::QueueOverflow), 2500u - 2);
  EXPECT_EQ(a.stats().frames_completed, 2u);
  EXPECT_EQ(a.stats().frames_lost_total(), ev.lost.size() + a.stats().lost_reports_dropped);
}

TEST(Assembler, ByteBudgetEvictsOldestAcrossStreams) {
  AssemblerConfig cfg;
  cfg.max_frame_bytes = 10000;
  cfg.max_bytes_in_flight = 25000;
  Assembler a(cfg);
  for (uint16_t stream = 0; stream < 6; ++stream) {
    auto pk = packetize(make_meta(0, stream), random_bytes(10000, stream));
    a.push(pk[0], stream);
    EXPECT_LE(a.stats().bytes_in_flight, 25000u);
  }
  EXPECT_EQ(a.stats().frames_in_flight, 2u);
  const auto ev = a.poll(6);
  ASSERT_EQ(ev.lost.size(), 4u);
  EXPECT_EQ(ev.lost[0].meta.stream_id, 0);  // first in, first given up
  EXPECT_EQ(ev.lost[0].reason, LossReason::Evicted);
  EXPECT_EQ(ev.lost[0].packets_received, 1);
}

TEST(Assembler, LimitsAreCheckedBeforeAllocating) {
  Assembler a;  // 64 MiB per frame, 1200-byte chunks
  auto make = [](uint32_t total, uint16_t count, uint16_t chunk, uint16_t index, size_t payload) {
    auto d = packetize(make_meta(1), random_bytes(10, 1))[0];
    d.resize(kPacketHeaderBytes + payload, 0x5A);
    put32(d, 20, total);
    put16(d, 24, index);
    put16(d, 26, count);
    put16(d, 28, chunk);
    put16(d, 30, uint32_t(payload));
    seal_packet(d);
    return d;
  };
  // 65535 x 65535 bytes claimed (4 GiB): refused, nothing allocated.
  const auto huge = make(uint32_t(65534u * 65535u + 1), 65535, 65535, 65534, 1);
  ASSERT_EQ(parse(huge), ParseResult::Ok);
  EXPECT_EQ(a.push(huge, 0), PacketFate::TooLarge);
  // Within the frame limit but with a chunk above max_payload_bytes.
  const auto wide = make(4000, 2, 2000, 1, 2000);
  ASSERT_EQ(parse(wide), ParseResult::Ok);
  EXPECT_EQ(a.push(wide, 0), PacketFate::TooLarge);
  // A decoded buffer above the limit: 16384 x 4096 pixels x 64 lights = 512 MiB.
  auto big_desc = packetize(make_meta(2), random_bytes(10, 1))[0];
  put16(big_desc, 32, 16384);
  put16(big_desc, 34, 4096);
  big_desc[5] = uint8_t(PassKind::Visibility);
  big_desc[36] = 64;
  seal_packet(big_desc);
  ASSERT_EQ(parse(big_desc), ParseResult::Ok);
  EXPECT_EQ(a.push(big_desc, 0), PacketFate::TooLarge);
  EXPECT_EQ(a.stats().peak_bytes_in_flight, 0u);
  EXPECT_EQ(a.stats().peak_frames_in_flight, 0u);
  EXPECT_EQ(a.streams(), 0u);
}

TEST(Assembler, InconsistentPacketsOfAFrameAreDropped) {
  Assembler a;
  const auto payload = random_bytes(3000, 8);
  const auto pk = packetize(make_meta(4), payload);  // 3 packets
  ASSERT_EQ(a.push(pk[0], 0), PacketFate::Accepted);
  // Same frame id, another description / codec / size: a different sender or a bug.
  auto other_desc = make_meta(4);
  other_desc.desc.width = 32;
  EXPECT_EQ(a.push(packetize(other_desc, payload)[1], 0), PacketFate::Inconsistent);
  auto other_codec = make_meta(4);
  other_codec.codec_id = codec_id("zstd");
  EXPECT_EQ(a.push(packetize(other_codec, payload)[1], 0), PacketFate::Inconsistent);
  EXPECT_EQ(a.push(packetize(make_meta(4), random_bytes(3700, 8))[2], 0), PacketFate::Inconsistent);
  // Same index, other sequence numbers.
  EXPECT_EQ(a.push(packetize(make_meta(4, 3, 10), payload)[0], 0), PacketFate::Inconsistent);
  // Same index and sequence number, other bytes.
  EXPECT_EQ(a.push(packetize(make_meta(4), random_bytes(3000, 9))[0], 0), PacketFate::Inconsistent);
  EXPECT_EQ(a.push(pk[0], 0), PacketFate::Duplicate);
  EXPECT_EQ(a.push(pk[1], 0), PacketFate::Accepted);
  EXPECT_EQ(a.push(pk[2], 0), PacketFate::Completed);
  const auto ev = a.poll(0);
  ASSERT_EQ(ev.completed.size(), 1u);
  EXPECT_EQ(ev.completed[0].encoded, payload);
  EXPECT_EQ(a.stats().count(PacketFate::Inconsistent), 5u);
  EXPECT_EQ(a.stats().packets_lost + a.packets_missing(), 0u);
}

TEST(Assembler, TimeoutGivesUpAFrame) {
  AssemblerConfig cfg;
  cfg.timeout_ms = 50;
  Assembler a(cfg);
  const auto pk = packetize(make_meta(1), random_bytes(3000, 1));
  a.push(pk[0], 100);
  a.push(pk[1], 140);
  EXPECT_TRUE(a.poll(150).lost.empty());  // exactly timeout_ms after the first packet: still open
  const auto ev = a.poll(151);
  ASSERT_EQ(ev.lost.size(), 1u);
  EXPECT_EQ(ev.lost[0].reason, LossReason::Timeout);
  EXPECT_EQ(ev.lost[0].packets_received, 2);
  EXPECT_EQ(ev.lost[0].packet_count, 3);
  EXPECT_EQ(a.stats().bytes_in_flight, 0u);
  // The last packet arrives too late: refused, no second report.
  EXPECT_EQ(a.push(pk[2], 160), PacketFate::FinishedFrame);
  EXPECT_TRUE(a.poll(1000).lost.empty());
  // A clock that goes back is ignored (time never runs backwards inside the assembler).
  const auto pk2 = packetize(make_meta(2, 3, 3), random_bytes(3000, 2));
  a.push(pk2[0], 0);
  EXPECT_TRUE(a.poll(1050).lost.empty());
  EXPECT_EQ(a.poll(1051).lost.size(), 1u);
}

TEST(Assembler, StaleFramesAndLateDelivery) {
  const auto old_pk = packetize(make_meta(1, 3, 0), random_bytes(2000, 1));
  const auto new_pk = packetize(make_meta(2, 3, 2), random_bytes(100, 2));
  {
    Assembler a;
    EXPECT_EQ(a.push(old_pk[0], 0), PacketFate::Accepted);
    EXPECT_EQ(a.push(new_pk[0], 1), PacketFate::Completed);  // supersedes frame 1
    EXPECT_EQ(a.push(old_pk[1], 2), PacketFate::FinishedFrame);
    const auto ev = a.poll(2);
    ASSERT_EQ(ev.completed.size(), 1u);
    ASSERT_EQ(ev.lost.size(), 1u);
    EXPECT_EQ(ev.lost[0].meta.frame_id, 1u);
    EXPECT_EQ(ev.lost[0].reason, LossReason::Superseded);
    // A frame older than the newest completed one, never seen before: refused and reported once.
    const auto older_pk = packetize(make_meta(0, 3, 100), random_bytes(2000, 3));
    EXPECT_EQ(a.push(older_pk[0], 3), PacketFate::Stale);
    EXPECT_EQ(a.push(older_pk[1], 3), PacketFate::FinishedFrame);
    EXPECT_EQ(a.poll(3).lost.size(), 1u);
  }
  {
    AssemblerConfig cfg;
    cfg.deliver_late_frames = true;
    Assembler a(cfg);
    a.push(old_pk[0], 0);
    a.push(new_pk[0], 1);
    EXPECT_EQ(a.push(old_pk[1], 2), PacketFate::Completed);
    const auto ev = a.poll(2);
    ASSERT_EQ(ev.completed.size(), 2u);
    EXPECT_FALSE(ev.completed[0].late);
    EXPECT_TRUE(ev.completed[1].late);
    EXPECT_EQ(a.stats().frames_completed_late, 1u);
  }
}

TEST(Assembler, StreamLimitAndIdleStreamsAreForgotten) {
  AssemblerConfig cfg;
  cfg.max_streams = 2;
  cfg.stream_idle_ms = 100;
  Assembler a(cfg);
  EXPECT_EQ(a.push(packetize(make_meta(0, 1), random_bytes(10, 1))[0], 0), PacketFate::Completed);
  EXPECT_EQ(a.push(packetize(make_meta(0, 2), random_bytes(10, 1))[0], 0), PacketFate::Completed);
  const auto third = packetize(make_meta(0, 3), random_bytes(10, 1))[0];
  EXPECT_EQ(a.push(third, 0), PacketFate::TooManyStreams);
  a.poll(101);
  EXPECT_EQ(a.streams(), 0u);
  EXPECT_EQ(a.push(third, 102), PacketFate::Completed);
}

TEST(Assembler, ConfigIsValidated) {
  AssemblerConfig c;
  c.max_frames_in_flight = 0;
  EXPECT_THROW(Assembler{c}, Error);
  c = {};
  c.max_bytes_in_flight = c.max_frame_bytes - 1;
  EXPECT_THROW(Assembler{c}, Error);
  c = {};
  c.max_payload_bytes = 70000;
  EXPECT_THROW(Assembler{c}, Error);
  c = {};
  c.timeout_ms = -1;
  EXPECT_THROW(Assembler{c}, Error);
}

// ---- Loss from sequence numbers

TEST(SequenceTracker, GapsReorderingDuplicatesAndWrap) {
  for (uint32_t start : {0u, 0xFFFFFF00u}) {  // also across the 2^32 wrap
    SequenceTracker t(64);
    uint64_t lost = 0;
    EXPECT_EQ(t.on_packet(start + 5, lost), SequenceTracker::Seen::New);
    EXPECT_EQ(t.on_packet(start + 3, lost), SequenceTracker::Seen::New);  // before the first seen
    EXPECT_EQ(t.on_packet(start + 9, lost), SequenceTracker::Seen::New);
    EXPECT_EQ(t.on_packet(start + 9, lost), SequenceTracker::Seen::Duplicate);
    EXPECT_EQ(t.missing(), 4u);  // 4, 6, 7, 8
    EXPECT_EQ(t.on_packet(start + 7, lost), SequenceTracker::Seen::New);
    EXPECT_EQ(t.missing(), 3u);
    EXPECT_EQ(lost, 0u);
    // 4, 6 and 8 leave the window when the newest is 8 + 64 ahead.
    t.on_packet(start + 9 + 64, lost);
    EXPECT_EQ(lost, 3u);
    EXPECT_EQ(t.missing(), 63u);  // 10 .. 72
    EXPECT_EQ(t.on_packet(start + 8, lost), SequenceTracker::Seen::Late);
    // A jump far beyond the window: 10..72 and 74..1072 are missing; all but the last 63
    // (still in the window) are counted at once, the rest at flush().
    t.on_packet(start + 9 + 64 + 1000, lost);
    EXPECT_EQ(lost, 3u + 63u + 999u - 63u);
    EXPECT_EQ(t.flush(), 63u);
    EXPECT_EQ(t.missing(), 0u);
  }
}

TEST(Assembler, SequenceGapsCountLostPackets) {
  AssemblerConfig cfg;
  cfg.reorder_window_packets = 64;
  Assembler a(cfg);
  uint32_t seq = 0;
  uint64_t dropped = 0;
  for (uint32_t frame = 0; frame < 50; ++frame) {
    const auto pk = packetize(make_meta(frame, 1, seq), random_bytes(1000, 1, frame), 300);  // 4 packets
    seq += uint32_t(pk.size());
    for (size_t i = 0; i < pk.size(); ++i) {
      if (frame % 5 == 2 && i == 1) {
        ++dropped;
        continue;
      }
      a.push(pk[i], frame);
    }
  }
  // Until the window has moved past them, the gaps are only "missing".
  EXPECT_EQ(a.stats().packets_lost + a.packets_missing(), dropped);
  const auto ev = a.flush(100);
  EXPECT_EQ(a.stats().packets_lost, dropped);
  EXPECT_EQ(a.packets_missing(), 0u);
  EXPECT_EQ(a.stats().frames_completed, 40u);
  EXPECT_EQ(a.stats().lost(LossReason::Superseded) + a.stats().lost(LossReason::Flushed), 10u);
}

// Independent loss at 1% and 5% on two streams of frames: every frame with a dropped packet is
// lost, every other frame completes with its bytes, and the packets counted lost from sequence
// numbers are exactly the ones dropped (but for those after a stream's last received packet,
// which no receiver can see).
TEST(Assembler, IndependentLossIsReportedConsistently) {
  for (double p_loss : {0.01, 0.05}) {
    AssemblerConfig cfg;
    cfg.timeout_ms = 40;
    Assembler a(cfg);
    std::map<std::pair<uint16_t, uint32_t>, std::vector<uint8_t>> sent;
    std::set<std::pair<uint16_t, uint32_t>> with_drop, all_dropped;
    std::map<uint16_t, uint32_t> next_seq;
    std::map<uint16_t, uint64_t> dropped_total, dropped_since_last_received;
    std::vector<AssembledFrame> completed;
    std::vector<LostFrame> lost;
    auto collect = [&](AssemblerEvents ev) {
      for (auto& f : ev.completed) completed.push_back(std::move(f));
      for (auto& l : ev.lost) lost.push_back(l);
    };
    for (uint32_t frame = 0; frame < 400; ++frame) {
      const int64_t now = int64_t(frame) * 16;
      for (uint16_t stream : {1, 2}) {
        const size_t size = 500 + size_t(rng_bits({5, stream, frame, 0, kStreamNetwork}) % 6000);
        auto payload = random_bytes(size, stream, frame);
        const auto pk = packetize(make_meta(frame, stream, next_seq[stream]), payload, 1000);
        size_t received = 0;
        for (size_t i = 0; i < pk.size(); ++i) {
          const uint32_t seq = next_seq[stream] + uint32_t(i);
          const bool drop = rng_uniform_double({uint64_t(p_loss * 1000), seq, 0, stream, kStreamNetwork}) < p_loss;
          if (drop) {
            ++dropped_total[stream];
            ++dropped_since_last_received[stream];
            with_drop.insert({stream, frame});
            continue;
          }
          dropped_since_last_received[stream] = 0;
          ++received;
          a.push(pk[i], now);
        }
        if (received == 0) all_dropped.insert({stream, frame});
        next_seq[stream] += uint32_t(pk.size());
        sent[{stream, frame}] = std::move(payload);
      }
      collect(a.poll(now));
    }
    collect(a.flush(400 * 16));

    ASSERT_FALSE(with_drop.empty());
    std::set<std::pair<uint16_t, uint32_t>> done, gone;
    for (const auto& f : completed) {
      const std::pair<uint16_t, uint32_t> key{f.meta.stream_id, f.meta.frame_id};
      EXPECT_EQ(f.encoded, sent[key]);
      EXPECT_TRUE(done.insert(key).second);
    }
    for (const auto& l : lost) EXPECT_TRUE(gone.insert({l.meta.stream_id, l.meta.frame_id}).second);
    for (const auto& [key, bytes] : sent) {
      if (with_drop.count(key)) {
        EXPECT_FALSE(done.count(key)) << key.first << "/" << key.second;
        // A frame with no packet left cannot be named by the receiver; the others are reported.
        EXPECT_EQ(gone.count(key), all_dropped.count(key) ? 0u : 1u) << key.first << "/" << key.second;
      } else {
        EXPECT_TRUE(done.count(key)) << key.first << "/" << key.second;
      }
    }
    uint64_t visible_drops = 0;
    for (uint16_t stream : {1, 2}) visible_drops += dropped_total[stream] - dropped_since_last_received[stream];
    EXPECT_EQ(a.stats().packets_lost, visible_drops) << p_loss;
    EXPECT_EQ(a.stats().frames_completed, sent.size() - with_drop.size());
    EXPECT_EQ(a.stats().frames_lost_total(), with_drop.size() - all_dropped.size());
  }
}

// ---- Forward error correction (core/net/fec.h)

// Feeds the packets whose bit in `keep` is set (in a shuffled order) to a fresh assembler and
// returns the one frame it completes, or nothing.
std::optional<std::vector<uint8_t>> deliver(const std::vector<std::vector<uint8_t>>& packets, uint64_t keep,
                                            uint64_t seed, AssemblerStats* stats = nullptr) {
  std::vector<size_t> order;
  for (size_t i = 0; i < packets.size(); ++i)
    if ((keep >> i) & 1u) order.push_back(i);
  shuffle(order, seed);
  Assembler a;
  for (size_t i : order) a.push(packets[i], 0);
  AssemblerEvents e = a.flush(1);
  if (stats) *stats = a.stats();
  if (e.completed.size() != 1) return std::nullopt;
  return std::move(e.completed[0].encoded);
}

TEST(Fec, EveryLossPatternUpToTheParityCountRebuildsTheFrame) {
  // 5 data packets (the last one short) and 2 parity packets: all 2^7 patterns.
  const std::vector<uint8_t> pass = random_bytes(4 * 300 + 123, 11);
  const int parity = fec_parity_count(5, 0.4, 0);
  ASSERT_EQ(parity, 2);
  const auto packets = packetize(make_meta(9), pass, 300, parity);
  ASSERT_EQ(packets.size(), 7u);
  for (size_t i = 5; i < 7; ++i) EXPECT_EQ(packets[i].size(), kPacketHeaderBytes + 300);  // shard size
  int rebuilt = 0;
  for (uint64_t keep = 0; keep < 128; ++keep) {
    const int lost = 7 - std::popcount(keep);
    AssemblerStats st;
    const auto got = deliver(packets, keep, keep, &st);
    const bool data_lost = (keep & 31u) != 31u;
    if (lost <= 2) {
      ASSERT_TRUE(got) << "lost " << lost << " pattern " << keep;
      EXPECT_EQ(*got, pass) << "pattern " << keep;
      // With every data packet delivered the frame may still complete early from parity (a
      // parity packet arrived before the last data packet); with one missing it must.
      if (data_lost) {
        EXPECT_EQ(st.frames_recovered, 1u);
      }
      rebuilt += data_lost;
    } else {
      // One loss more than the parity count: some data packet is missing and 4 shards cannot
      // rebuild 5; the frame is reported lost.
      EXPECT_FALSE(got) << "lost " << lost << " pattern " << keep;
      EXPECT_EQ(st.frames_lost_total(), keep ? 1u : 0u);
    }
    // The simulator's rule says the same.
    FecLayout l;
    ASSERT_TRUE(fec_layout(5, 2, l));
    std::vector<bool> arrived(7);
    for (size_t i = 0; i < 7; ++i) arrived[i] = (keep >> i) & 1u;
    EXPECT_EQ(fec_can_rebuild(l, arrived), lost <= 2);
  }
  EXPECT_EQ(rebuilt, 5 + 20);  // patterns of 1 or 2 losses that include a data packet
}

TEST(Fec, InterleavedBlocksSpreadABurst) {
  // 300 data packets: 3 blocks of 100 (data packet i in block i % 3), 10 % parity: 10 each.
  const std::vector<uint8_t> pass = random_bytes(300 * 64 - 7, 12);
  const int parity = fec_parity_count(300, 0.1, 2);
  ASSERT_EQ(parity, 30);
  FecLayout l;
  ASSERT_TRUE(fec_layout(300, parity, l));
  EXPECT_EQ(l.blocks, 3);
  EXPECT_EQ(l.per_block, 10);
  const auto packets = packetize(make_meta(4), pass, 64, parity);
  ASSERT_EQ(packets.size(), 330u);
  for (const int burst : {30, 31}) {
    Assembler a;
    for (size_t i = 0; i < packets.size(); ++i)
      if (i < 100 || i >= 100 + size_t(burst)) a.push(packets[i], 0);
    AssemblerEvents e = a.flush(1);
    if (burst == 30) {  // 10 lost in each block: exactly its parity
      ASSERT_EQ(e.completed.size(), 1u);
      EXPECT_EQ(e.completed[0].encoded, pass);
      EXPECT_EQ(a.stats().packets_recovered, 30u);
    } else {
      EXPECT_TRUE(e.completed.empty());
      ASSERT_EQ(e.lost.size(), 1u);
    }
  }
  // The minimum applies per block; the cap keeps a block within 255 shards.
  EXPECT_EQ(fec_parity_count(3, 0.0, 2), 2);
  EXPECT_EQ(fec_parity_count(3, 0.0, 0), 0);
  EXPECT_EQ(fec_parity_count(10, 0.2, 1), 2);
  EXPECT_EQ(fec_parity_count(128, 1.0, 0), 127);
  EXPECT_THROW(fec_parity_count(10, 1.5, 0), Error);
  EXPECT_THROW(fec_parity_count(10, 0.1, 255), Error);
}

TEST(Fec, DamagedOrForgedParityIsCaught) {
  const std::vector<uint8_t> pass = random_bytes(1000, 13);
  auto packets = packetize(make_meta(2), pass, 250, 2);  // 4 data, 2 parity
  ASSERT_EQ(packets.size(), 6u);
  // A flipped bit of a parity payload fails the checksum: it cannot poison the rebuild.
  auto bad = packets[5];
  bad.back() ^= 0x10;
  EXPECT_EQ(parse(bad), ParseResult::BadChecksum);
  Assembler a;
  a.push(packets[0], 0);
  a.push(packets[1], 0);
  EXPECT_EQ(a.push(bad, 0), PacketFate::BadChecksum);
  EXPECT_EQ(a.push(packets[4], 0), PacketFate::Accepted);  // 3 of 4: not yet
  EXPECT_EQ(a.push(packets[5], 0), PacketFate::Completed);
  AssemblerEvents e = a.poll(0);
  ASSERT_EQ(e.completed.size(), 1u);
  EXPECT_EQ(e.completed[0].encoded, pass);
  // Header fields that form no FEC layout are refused before anything is stored.
  auto edit = [&](size_t i, auto&& change) {
    auto d = packets[i];
    change(d);
    seal_packet(d);
    return parse(d);
  };
  EXPECT_EQ(edit(0, [](auto& d) { put16(d, 24, 6); }), ParseResult::BadIndex);  // index >= count + parity
  EXPECT_EQ(edit(4,
                 [](auto& d) {
                   put16(d, 30, 200);
                   d.resize(kPacketHeaderBytes + 200);
                 }),
            ParseResult::BadLength);
  // Parity on an empty pass, and a parity count that is not a multiple of the blocks.
  auto empty = packetize(make_meta(3), {}, 250, 2);
  ASSERT_EQ(empty.size(), 1u);  // an empty pass gets no parity
  EXPECT_EQ(edit(0, [](auto&) {}), ParseResult::Ok);
  auto e0 = empty[0];
  put16(e0, 38, 1);
  seal_packet(e0);
  EXPECT_EQ(parse(e0), ParseResult::BadIndex);
  auto big = packetize(make_meta(3), random_bytes(200 * 10, 14), 10);  // 200 data packets: 2 blocks
  auto b0 = big[0];
  put16(b0, 38, 3);
  seal_packet(b0);
  EXPECT_EQ(parse(b0), ParseResult::BadIndex);
  EXPECT_THROW(packetize(make_meta(3), random_bytes(200 * 10, 14), 10, 3), Error);
}

}  // namespace
}  // namespace dhr
