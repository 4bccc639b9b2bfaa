#include "core/net/assembler.h"

#include "core/base/error.h"

#include <algorithm>
#include <bit>
#include <cstring>

namespace dhr {
namespace {

// Frame ids and sequence numbers wrap modulo 2^32; "a is older than b" is decided by the
// signed distance, as in serial number arithmetic (RFC 1982).
bool older(uint32_t a, uint32_t b) { return int32_t(a - b) < 0; }

PacketFate fate_of(ParseResult r) {
  static_assert(int(PacketFate::BadReserved) - int(PacketFate::TooShort) ==
                int(ParseResult::BadReserved) - int(ParseResult::TooShort));
  return PacketFate(int(PacketFate::TooShort) + int(r) - int(ParseResult::TooShort));
}

uint32_t stream_key(const PacketMeta& m) { return (uint32_t(m.stream_id) << 8) | uint32_t(m.desc.kind); }

// Bound on queued LostFrame reports between two poll() calls (they are small; the bound only
// matters when a caller never polls).
constexpr size_t kMaxQueuedLostReports = 4096;

}  // namespace

void AssemblerConfig::validate() const {
  if (max_payload_bytes < 1 || max_payload_bytes > UINT16_MAX)
    fail("assembler: max_payload_bytes {} out of range 1..65535", max_payload_bytes);
  if (max_frame_bytes < 1 || max_frame_bytes > UINT32_MAX)
    fail("assembler: max_frame_bytes {} out of range 1..{}", max_frame_bytes, uint64_t(UINT32_MAX));
  if (max_bytes_in_flight < max_frame_bytes)
    fail("assembler: max_bytes_in_flight {} must be at least max_frame_bytes {}", max_bytes_in_flight, max_frame_bytes);
  if (max_frames_in_flight < 1 || max_frames_in_flight > 1024)
    fail("assembler: max_frames_in_flight {} out of range 1..1024", max_frames_in_flight);
  if (max_streams < 1 || max_streams > 65536) fail("assembler: max_streams {} out of range 1..65536", max_streams);
  if (timeout_ms < 0) fail("assembler: timeout_ms {} must be >= 0", timeout_ms);
  if (reorder_window_packets < 1 || reorder_window_packets > (1u << 20))
    fail("assembler: reorder_window_packets {} out of range 1..{}", reorder_window_packets, 1u << 20);
  if (stream_idle_ms < 0) fail("assembler: stream_idle_ms {} must be >= 0", stream_idle_ms);
}

const char* packet_fate_name(PacketFate f) {
  switch (f) {
    case PacketFate::Accepted: return "accepted";
    case PacketFate::Completed: return "completed";
    case PacketFate::TooShort: return "too_short";
    case PacketFate::BadMagic: return "bad_magic";
    case PacketFate::BadVersion: return "bad_version";
    case PacketFate::BadChecksum: return "bad_checksum";
    case PacketFate::BadLength: return "bad_length";
    case PacketFate::BadIndex: return "bad_index";
    case PacketFate::BadDesc: return "bad_desc";
    case PacketFate::BadReserved: return "bad_reserved";
    case PacketFate::TooLarge: return "too_large";
    case PacketFate::Duplicate: return "duplicate";
    case PacketFate::Inconsistent: return "inconsistent";
    case PacketFate::Stale: return "stale";
    case PacketFate::FinishedFrame: return "finished_frame";
    case PacketFate::Evicted: return "evicted";
    case PacketFate::TooManyStreams: return "too_many_streams";
  }
  return "unknown";
}

const char* loss_reason_name(LossReason r) {
  switch (r) {
    case LossReason::Timeout: return "timeout";
    case LossReason::Superseded: return "superseded";
    case LossReason::Evicted: return "evicted";
    case LossReason::Flushed: return "flushed";
    case LossReason::QueueOverflow: return "queue_overflow";
  }
  return "unknown";
}

uint64_t AssemblerStats::frames_lost_total() const {
  uint64_t n = 0;
  for (uint64_t v : frames_lost) n += v;
  return n;
}

uint64_t AssemblerStats::packets_dropped() const {
  uint64_t n = 0;
  for (int i = int(PacketFate::TooShort); i < kPacketFateCount; ++i) n += packets[size_t(i)];
  return n;
}

// ---- SequenceTracker

SequenceTracker::SequenceTracker(uint32_t window_packets)
    : window_(std::max<uint32_t>(64, std::bit_ceil(std::max<uint32_t>(window_packets, 1)))),
      mask_(window_ - 1),
      bits_(window_ / 64, 0) {}

SequenceTracker::Seen SequenceTracker::on_packet(uint32_t seq, uint64_t& lost) {
  if (!started_) {
    std::fill(bits_.begin(), bits_.end(), 0);
    started_ = true;
    highest_ = floor_ = seq;
    set(seq);
    return Seen::New;
  }
  const int64_t d = int32_t(seq - highest_);
  if (d > 0) {
    // Sequence numbers (highest - W, seq - W] leave the window: those not received are lost.
    // The ones at most `highest` are looked up; any beyond it were never received.
    const uint32_t leaving_known = uint32_t(std::min<int64_t>(d, window_));
    for (uint32_t k = 0; k < leaving_known; ++k) {
      const uint32_t s = highest_ - window_ + 1 + k;
      if (!older(s, floor_) && !test(s)) ++lost;
    }
    if (d > int64_t(window_)) lost += uint64_t(d - window_);
    // The slots of the sequence numbers now entering the window start empty.
    for (uint32_t k = 1; k <= leaving_known; ++k) clear(highest_ + k);
    highest_ = seq;
    set(seq);
    // Keep the floor inside the window so that the wrap-around comparisons stay meaningful.
    const uint32_t oldest_in_window = highest_ - window_ + 1;
    if (older(floor_, oldest_in_window)) floor_ = oldest_in_window;
    return Seen::New;
  }
  if (-d >= int64_t(window_)) return Seen::Late;
  if (older(seq, floor_)) {
    // Reordered before the first packet we saw: the stream started earlier than we thought.
    // Its slot is empty (slots are cleared as they enter the window, and all were at start).
    floor_ = seq;
    set(seq);
    return Seen::New;
  }
  if (test(seq)) return Seen::Duplicate;
  set(seq);
  return Seen::New;
}

uint64_t SequenceTracker::missing() const {
  if (!started_) return 0;
  uint64_t n = 0;
  for (uint32_t s = floor_;; ++s) {
    if (!test(s)) ++n;
    if (s == highest_) break;
  }
  return n;
}

uint64_t SequenceTracker::flush() {
  const uint64_t n = missing();
  started_ = false;
  return n;
}

// ---- Assembler

Assembler::Assembler(AssemblerConfig config) : config_(config) { config_.validate(); }

int64_t Assembler::advance_clock(int64_t now_ms) {
  now_ms_ = std::max(now_ms_, now_ms);
  return now_ms_;
}

uint64_t Assembler::packets_missing() const {
  uint64_t n = 0;
  for (const auto& [key, s] : streams_) n += s.sequence.missing();
  return n;
}

void Assembler::add_in_flight(const Frame& f) {
  stats_.bytes_in_flight += f.held();
  ++stats_.frames_in_flight;
  stats_.peak_bytes_in_flight = std::max(stats_.peak_bytes_in_flight, stats_.bytes_in_flight);
  stats_.peak_frames_in_flight = std::max(stats_.peak_frames_in_flight, stats_.frames_in_flight);
}

void Assembler::remove_in_flight(const Frame& f) {
  stats_.bytes_in_flight -= f.held();
  --stats_.frames_in_flight;
}

void Assembler::report_lost(const LostFrame& lost) {
  ++stats_.frames_lost[size_t(lost.reason)];
  if (pending_.lost.size() >= kMaxQueuedLostReports) {
    ++stats_.lost_reports_dropped;  // still counted in frames_lost
    return;
  }
  pending_.lost.push_back(lost);
}

void Assembler::remember_finished(Stream& s, uint32_t frame_id) {
  // Twice the in-flight limit: enough to recognise the late packets of frames just finished.
  const size_t ring = size_t(2 * config_.max_frames_in_flight);
  if (s.finished.size() < ring) {
    s.finished.push_back(frame_id);
  } else {
    s.finished[s.finished_next] = frame_id;
    s.finished_next = (s.finished_next + 1) % ring;
  }
}

bool Assembler::recently_finished(const Stream& s, uint32_t frame_id) const {
  return std::find(s.finished.begin(), s.finished.end(), frame_id) != s.finished.end();
}

void Assembler::give_up(Stream& s, size_t i, LossReason reason) {
  Frame& f = s.frames[i];
  report_lost({f.meta, reason, f.received, f.count});
  remember_finished(s, f.meta.frame_id);
  remove_in_flight(f);
  s.frames.erase(s.frames.begin() + std::ptrdiff_t(i));
}

void Assembler::complete(Stream& s, size_t i) {
  remove_in_flight(s.frames[i]);
  Frame f = std::move(s.frames[i]);
  s.frames.erase(s.frames.begin() + std::ptrdiff_t(i));
  remember_finished(s, f.meta.frame_id);
  const bool late = s.any_completed && older(f.meta.frame_id, s.newest_completed);
  if (!late) {
    s.any_completed = true;
    s.newest_completed = f.meta.frame_id;
    if (!config_.deliver_late_frames) {
      // In-order delivery: the older partial frames can no longer be used.
      for (size_t k = s.frames.size(); k-- > 0;)
        if (older(s.frames[k].meta.frame_id, f.meta.frame_id)) give_up(s, k, LossReason::Superseded);
    }
  }
  ++stats_.frames_completed;
  if (late) ++stats_.frames_completed_late;
  // A bounded queue: a caller that never polls loses the oldest completed frames, reported.
  const size_t max_queued = size_t(config_.max_streams) * size_t(config_.max_frames_in_flight);
  if (pending_.completed.size() >= max_queued) {
    const AssembledFrame& old = pending_.completed.front();
    --stats_.frames_completed;
    if (old.late) --stats_.frames_completed_late;
    report_lost({old.meta, LossReason::QueueOverflow, old.packet_count, old.packet_count});
    pending_.completed.erase(pending_.completed.begin());
  }
  f.bytes.resize(f.total_bytes);  // the FEC shards' padding
  pending_.completed.push_back(
      {f.meta, std::move(f.bytes), f.count, late, f.first_packet_ms, now_ms_, uint16_t(f.fec.parity)});
}

// Rebuilds the missing data packets of a frame whose every FEC block has as many packets as
// data packets (core/net/fec.h). False when the decoder refuses (cannot happen for valid layouts).
bool Assembler::rebuild(Frame& f) {
  const FecLayout& l = f.fec;
  const size_t shard = fec_shard_bytes(f.total_bytes, f.chunk_bytes);
  const auto has = [&](int i) { return (f.have[size_t(i) / 64] >> (i % 64)) & 1u; };
  uint64_t rebuilt = 0;
  for (int b = 0; b < l.blocks; ++b) {
    const int k = l.block_data(b);
    std::vector<int> present, missing;
    std::vector<const uint8_t*> shards;
    std::vector<uint8_t*> out;
    for (int j = 0; j < k; ++j) {
      const int i = b + j * l.blocks;
      uint8_t* p = f.bytes.data() + size_t(i) * shard;
      if (has(i)) {
        if (int(present.size()) < k) present.push_back(j), shards.push_back(p);
      } else {
        missing.push_back(j), out.push_back(p);
      }
    }
    if (missing.empty()) continue;
    for (int j = 0; j < l.per_block && int(present.size()) < k; ++j) {
      const int i = f.count + b * l.per_block + j;
      if (has(i))
        present.push_back(k + j), shards.push_back(f.parity_bytes.data() + size_t(b * l.per_block + j) * shard);
    }
    if (int(present.size()) < k || !rs_decode(k, l.per_block, shard, present, shards.data(), missing, out.data()))
      return false;
    rebuilt += missing.size();
  }
  ++stats_.frames_recovered;
  stats_.packets_recovered += rebuilt;
  return true;
}

// Gives up the partial frames that arrived first until `bytes` more fit the budget.
void Assembler::make_room(size_t bytes) {
  while (stats_.bytes_in_flight + bytes > config_.max_bytes_in_flight) {
    Stream* oldest_stream = nullptr;
    size_t oldest_index = 0;
    for (auto& [key, s] : streams_)
      for (size_t i = 0; i < s.frames.size(); ++i)
        if (!oldest_stream || s.frames[i].first_packet_ms < oldest_stream->frames[oldest_index].first_packet_ms) {
          oldest_stream = &s;
          oldest_index = i;
        }
    if (!oldest_stream) return;  // nothing left to give up (cannot happen: bytes <= budget)
    give_up(*oldest_stream, oldest_index, LossReason::Evicted);
  }
}

PacketFate Assembler::push(std::span<const uint8_t> datagram, int64_t now_ms) {
  const int64_t now = advance_clock(now_ms);
  ++stats_.datagrams;
  const auto count_fate = [&](PacketFate f) {
    ++stats_.packets[size_t(f)];
    return f;
  };

  ParsedPacket p;
  if (const ParseResult r = parse_packet(datagram, p); r != ParseResult::Ok) return count_fate(fate_of(r));

  // Limits before any allocation.
  if (p.chunk_bytes > config_.max_payload_bytes || p.total_bytes > config_.max_frame_bytes ||
      p.meta.desc.byte_size() > config_.max_frame_bytes)
    return count_fate(PacketFate::TooLarge);

  const uint32_t key = stream_key(p.meta);
  auto it = streams_.find(key);
  if (it == streams_.end()) {
    if (streams_.size() >= size_t(config_.max_streams)) return count_fate(PacketFate::TooManyStreams);
    it = streams_.emplace(key, Stream(config_.reorder_window_packets)).first;
  }
  Stream& s = it->second;
  s.last_packet_ms = now;

  // Sequence numbers are recorded only for packets that belong to their frame (not for
  // inconsistent ones, which may be forged or from another sender), so that a gap is a loss.
  const auto record_sequence = [&]() {
    const auto seen = s.sequence.on_packet(p.sequence, stats_.packets_lost);
    if (seen == SequenceTracker::Seen::Late) ++stats_.packets_late;
    return seen;
  };

  const uint32_t frame_id = p.meta.frame_id;
  auto fit =
      std::find_if(s.frames.begin(), s.frames.end(), [&](const Frame& f) { return f.meta.frame_id == frame_id; });
  if (fit == s.frames.end()) {
    if (recently_finished(s, frame_id))
      return count_fate(record_sequence() == SequenceTracker::Seen::Duplicate ? PacketFate::Duplicate
                                                                              : PacketFate::FinishedFrame);
    if (!config_.deliver_late_frames && s.any_completed && older(frame_id, s.newest_completed)) {
      // Never seen and already superseded: report it once (it joins the finished ring).
      record_sequence();
      report_lost({p.meta, LossReason::Superseded, 0, p.count});
      remember_finished(s, frame_id);
      return count_fate(PacketFate::Stale);
    }
    if (s.frames.size() >= size_t(config_.max_frames_in_flight)) {
      size_t oldest = 0;
      for (size_t i = 1; i < s.frames.size(); ++i)
        if (older(s.frames[i].meta.frame_id, s.frames[oldest].meta.frame_id)) oldest = i;
      if (older(frame_id, s.frames[oldest].meta.frame_id)) {
        record_sequence();
        report_lost({p.meta, LossReason::Evicted, 0, p.count});
        remember_finished(s, frame_id);
        return count_fate(PacketFate::Evicted);
      }
      give_up(s, oldest, LossReason::Evicted);
    }
    FecLayout fec;
    fec_layout(p.count, p.parity, fec);  // parse_packet checked it
    const size_t shard = fec_shard_bytes(p.total_bytes, p.chunk_bytes);
    const size_t data_bytes = p.parity ? size_t(p.count) * shard : size_t(p.total_bytes);
    const size_t parity_bytes = size_t(p.parity) * shard;
    if (data_bytes + parity_bytes > config_.max_frame_bytes) return count_fate(PacketFate::TooLarge);
    make_room(data_bytes + parity_bytes);
    Frame f;
    f.meta = p.meta;
    f.total_bytes = p.total_bytes;
    f.count = p.count;
    f.chunk_bytes = p.chunk_bytes;
    f.fec = fec;
    f.first_packet_ms = now;
    f.bytes.resize(data_bytes);
    f.parity_bytes.resize(parity_bytes);
    f.block_have.assign(size_t(fec.blocks), 0);
    f.have.assign((size_t(p.count) + p.parity + 63) / 64, 0);
    add_in_flight(f);
    s.frames.push_back(std::move(f));
    fit = s.frames.end() - 1;
  } else {
    const Frame& f = *fit;
    // Sequence numbers are consecutive within a frame, so first_sequence must agree too.
    if (p.total_bytes != f.total_bytes || p.count != f.count || p.chunk_bytes != f.chunk_bytes ||
        p.parity != f.fec.parity || p.meta.desc != f.meta.desc || p.meta.codec_id != f.meta.codec_id ||
        p.meta.first_sequence != f.meta.first_sequence)
      return count_fate(PacketFate::Inconsistent);
  }

  Frame& f = *fit;
  uint64_t& word = f.have[p.index / 64];
  const uint64_t bit = uint64_t(1) << (p.index % 64);
  uint8_t* dst = p.is_parity() ? f.parity_bytes.data() + size_t(p.index - p.count) * p.payload.size()
                               : f.bytes.data() + p.offset();
  if (word & bit) {
    // Same index and sequence number (checked above): a duplicate, unless the bytes differ.
    const bool same = p.payload.empty() || std::memcmp(dst, p.payload.data(), p.payload.size()) == 0;
    return count_fate(same ? PacketFate::Duplicate : PacketFate::Inconsistent);
  }
  record_sequence();
  if (!p.payload.empty()) std::memcpy(dst, p.payload.data(), p.payload.size());
  word |= bit;
  ++f.received;
  if (!p.is_parity()) ++f.received_data;
  bool done = f.received_data == f.count;
  if (!done && f.fec.parity) {
    ++f.block_have[size_t(f.fec.block_of(p.index))];
    done = fec_blocks_complete(f.fec, f.block_have) && rebuild(f);
  }
  if (done) {
    complete(s, size_t(fit - s.frames.begin()));
    return count_fate(PacketFate::Completed);
  }
  return count_fate(PacketFate::Accepted);
}

AssemblerEvents Assembler::poll(int64_t now_ms) {
  const int64_t now = advance_clock(now_ms);
  for (auto it = streams_.begin(); it != streams_.end();) {
    Stream& s = it->second;
    for (size_t k = s.frames.size(); k-- > 0;) {
      // now >= first_packet_ms (the clock never goes back), so the unsigned difference is exact.
      if (uint64_t(now) - uint64_t(s.frames[k].first_packet_ms) > uint64_t(config_.timeout_ms))
        give_up(s, k, LossReason::Timeout);
    }
    if (s.frames.empty() && uint64_t(now) - uint64_t(s.last_packet_ms) > uint64_t(config_.stream_idle_ms)) {
      stats_.packets_lost += s.sequence.flush();
      it = streams_.erase(it);
    } else {
      ++it;
    }
  }
  AssemblerEvents out = std::move(pending_);
  pending_ = {};
  return out;
}

AssemblerEvents Assembler::flush(int64_t now_ms) {
  advance_clock(now_ms);
  for (auto& [key, s] : streams_) {
    while (!s.frames.empty()) give_up(s, 0, LossReason::Flushed);
    stats_.packets_lost += s.sequence.flush();
  }
  AssemblerEvents out = std::move(pending_);
  pending_ = {};
  return out;
}

}  // namespace dhr
