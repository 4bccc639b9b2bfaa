// libFuzzer target: the Assembler driven by a program read from the input. The program
// generates frames (known contents, streams 0..2), delivers their packets in order, out of
// order, twice, or not at all, flips bits, truncates, injects raw datagrams (resealed or not),
// and advances the virtual clock. Checked after every step: memory stays within the limits;
// every completed frame of a generated stream has exactly the bytes that were sent (injected
// datagrams are confined to stream ids >= 0x8000, so they can never be mistaken for them).
#include "core/base/rng.h"
#include "core/net/assembler.h"
#include "tests/fuzz/fuzz_common.h"

#include <deque>
#include <map>
#include <vector>

namespace {

using namespace dhr;

constexpr size_t kMaxPending = 2048;

uint8_t content_byte(uint16_t stream, uint32_t frame, size_t i) {
  return uint8_t(rng_bits({0xF022, uint32_t(i), frame, stream, kStreamNetwork}));
}

struct Harness {
  explicit Harness(const AssemblerConfig& cfg) : a(cfg) {}
  Assembler a;
  std::deque<std::vector<uint8_t>> pending;  // generated, not yet delivered
  std::map<std::pair<uint16_t, uint32_t>, std::vector<uint8_t>> sent;
  uint32_t next_frame[3] = {0, 0, 0};
  uint32_t next_seq[3] = {0, 0, 0};
  int64_t now_ms = 0;

  void check_limits() const {
    const auto& st = a.stats();
    const auto& c = a.config();
    DHR_FUZZ_CHECK(st.bytes_in_flight <= c.max_bytes_in_flight);
    DHR_FUZZ_CHECK(st.frames_in_flight <= size_t(c.max_streams) * size_t(c.max_frames_in_flight));
    DHR_FUZZ_CHECK(a.streams() <= size_t(c.max_streams));
  }

  void check(AssemblerEvents ev) {
    for (const auto& f : ev.completed) {
      DHR_FUZZ_CHECK(f.encoded.size() <= a.config().max_frame_bytes);
      if (f.meta.stream_id >= 0x8000) continue;  // injected: any bytes are possible
      const auto it = sent.find({f.meta.stream_id, f.meta.frame_id});
      DHR_FUZZ_CHECK(it != sent.end());
      DHR_FUZZ_CHECK(f.encoded == it->second);
    }
    for (const auto& l : ev.lost) DHR_FUZZ_CHECK(l.packets_received <= l.packet_count);
  }

  void deliver(std::span<const uint8_t> d) {
    a.push(d, now_ms);
    check_limits();
  }

  void generate(fuzz::Reader& r) {
    const uint16_t stream = uint16_t(r.u8() % 3);
    const size_t size = r.u16() % 9000;        // some above max_frame_bytes
    const size_t chunk = 64 + r.u16() % 1337;  // above 1200 is refused as TooLarge
    PacketMeta m;
    m.stream_id = stream;
    m.desc = {PassKind::Ao, 64, 48, 1, 255};
    m.frame_id = next_frame[stream]++;
    m.codec_id = 1;
    m.first_sequence = next_seq[stream];
    std::vector<uint8_t> bytes(size);
    for (size_t i = 0; i < size; ++i) bytes[i] = content_byte(stream, m.frame_id, i);
    auto packets = packetize(m, bytes, chunk);
    next_seq[stream] += uint32_t(packets.size());
    sent[{stream, m.frame_id}] = std::move(bytes);
    for (auto& p : packets) {
      if (pending.size() >= kMaxPending) pending.pop_front();
      pending.push_back(std::move(p));
    }
  }
};

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  fuzz::Reader r(data, size);
  AssemblerConfig cfg;
  cfg.max_frames_in_flight = 1 + r.u8() % 8;
  cfg.max_streams = 1 + r.u8() % 5;
  cfg.max_frame_bytes = size_t(1) << 13;  // small, to keep runs fast; passes above are refused
  cfg.max_bytes_in_flight = cfg.max_frame_bytes * (1 + r.u8() % 4);
  cfg.timeout_ms = r.u8();
  const uint8_t flags = r.u8();
  cfg.deliver_late_frames = flags & 1;
  cfg.reorder_window_packets = 64u << (flags >> 1 & 3);
  cfg.stream_idle_ms = 500;
  Harness h(cfg);

  for (int steps = 0; !r.empty() && steps < 4096; ++steps) {
    const uint8_t op = r.u8();
    const size_t pick = r.u16();
    switch (op & 7) {
      case 0: h.generate(r); break;
      case 1:  // in order
        if (!h.pending.empty()) {
          h.deliver(h.pending.front());
          h.pending.pop_front();
        }
        break;
      case 2:  // out of order
        if (!h.pending.empty()) {
          const size_t k = pick % h.pending.size();
          h.deliver(h.pending[k]);
          h.pending.erase(h.pending.begin() + std::ptrdiff_t(k));
        }
        break;
      case 3:  // duplicate
        if (!h.pending.empty()) h.deliver(h.pending[pick % h.pending.size()]);
        break;
      case 4:  // lost on the link
        if (!h.pending.empty()) h.pending.erase(h.pending.begin() + std::ptrdiff_t(pick % h.pending.size()));
        break;
      case 5:  // one bit flipped
        if (!h.pending.empty()) {
          auto d = h.pending[pick % h.pending.size()];
          const size_t bit = r.u16() % (d.size() * 8);
          d[bit / 8] ^= uint8_t(1u << (bit % 8));
          h.deliver(d);
        }
        break;
      case 6:  // truncated
        if (!h.pending.empty()) {
          auto d = h.pending[pick % h.pending.size()];
          d.resize(r.u16() % d.size());
          h.deliver(d);
        }
        break;
      case 7: {  // raw datagram from the input, confined to stream ids >= 0x8000
        std::vector<uint8_t> d;
        const auto raw = r.take(pick % 1400);
        d.assign(raw.begin(), raw.end());
        if (d.size() > 7) d[7] |= 0x80;
        if ((op & 8) && d.size() >= kPacketHeaderBytes) seal_packet(d);
        h.deliver(d);
        break;
      }
    }
    if (op & 0x10) {
      h.now_ms += op >> 5;
      h.check(h.a.poll(h.now_ms));
    }
  }
  h.check(h.a.flush(h.now_ms + 1));
  DHR_FUZZ_CHECK(h.a.stats().frames_in_flight == 0 && h.a.stats().bytes_in_flight == 0);
  return 0;
}
