// The receiver side of core/net/packet.h: collects the packets of each (stream, pass, frame) back
// into the encoded pass, with bounded memory, and reports which frames completed and which were
// lost (docs/architecture.md, "Packets and the network": a pass of a frame is usable when all its
// data packets arrived, or enough of its data and parity packets to rebuild them: core/net/fec.h).
//
// Every limit is checked before anything is allocated: a packet's header must pass
// parse_packet(), its chunk must be at most max_payload_bytes, its pass (total encoded bytes)
// and its decoded buffer (desc.byte_size()) at most max_frame_bytes; at most
// max_frames_in_flight partial frames per stream, max_streams streams and max_bytes_in_flight
// bytes in all partial frames are held (the oldest frame is given up to make room).
//
// Time is virtual: the caller passes its clock (ms) to push() and poll(); nothing here reads
// a clock, so results are deterministic. Loss is found from sequence numbers: a sequence
// number still missing when the stream's newest sequence number is reorder_window_packets
// ahead of it (or at flush()) is a lost packet. A frame is lost when it is given up: timed
// out, superseded by a newer completed frame, evicted to respect a limit, or flushed.
#pragma once

#include "core/net/fec.h"
#include "core/net/packet.h"

#include <array>
#include <cstdint>
#include <map>
#include <span>
#include <vector>

namespace dhr {

struct AssemblerConfig {
  size_t max_payload_bytes = kDefaultMaxPayloadBytes;  // larger chunks are refused (TooLarge)
  size_t max_frame_bytes = size_t(64) << 20;           // limit on a pass's encoded and decoded size
  size_t max_bytes_in_flight = size_t(256) << 20;      // all partial frames together
  int max_frames_in_flight = 8;                        // partial frames per stream
  int max_streams = 16;                                // (stream id, pass) pairs tracked at once
  int64_t timeout_ms = 200;                            // a frame not complete this long after its first packet is lost
  // false: once a frame of a stream completes, older partial frames of that stream are given
  // up (Superseded) and packets of older frames are refused, so frames are delivered in order.
  // true: older frames still complete and are delivered, marked late.
  bool deliver_late_frames = false;
  uint32_t reorder_window_packets = 1024;  // rounded up to a power of two, at least 64
  int64_t stream_idle_ms = 10000;          // poll() forgets a stream with nothing in flight this long
  // Throws dhr::Error naming the field when a value is out of range.
  void validate() const;
};

// What became of a datagram given to push().
enum class PacketFate : uint8_t {
  Accepted = 0,  // stored in a partial frame
  Completed,     // stored, and it completed its frame
  // Refused by parse_packet() (same order as ParseResult):
  TooShort,
  BadMagic,
  BadVersion,
  BadChecksum,
  BadLength,
  BadIndex,
  BadDesc,
  BadReserved,
  TooLarge,        // chunk, pass or decoded buffer above the configured limits
  Duplicate,       // this packet was received already (same bytes)
  Inconsistent,    // disagrees with its frame's first packet (count, total, chunk, desc, codec,
                   // or a packet index received before with other bytes)
  Stale,           // its frame is older than the newest completed one (deliver_late_frames off)
  FinishedFrame,   // its frame was completed or given up already
  Evicted,         // its frame is older than every partial frame of a full stream
  TooManyStreams,  // max_streams streams are active
};
constexpr int kPacketFateCount = 17;
const char* packet_fate_name(PacketFate f);

enum class LossReason : uint8_t {
  Timeout = 0,    // not complete timeout_ms after its first packet
  Superseded,     // a newer frame of its stream completed first (deliver_late_frames off)
  Evicted,        // given up to respect max_frames_in_flight or max_bytes_in_flight
  Flushed,        // still partial at flush()
  QueueOverflow,  // completed, but poll() was not called before the queue filled
};
constexpr int kLossReasonCount = 5;
const char* loss_reason_name(LossReason r);

struct AssembledFrame {
  PacketMeta meta;
  std::vector<uint8_t> encoded;  // exactly the bytes given to packetize()
  uint16_t packet_count = 0;
  bool late = false;  // older than a frame of its stream delivered before
  int64_t first_packet_ms = 0;
  int64_t completed_ms = 0;
  uint16_t parity_count = 0;  // its FEC parity packets (their sequence numbers follow the data's)
};

struct LostFrame {
  PacketMeta meta;
  LossReason reason = LossReason::Timeout;
  uint16_t packets_received = 0;
  uint16_t packet_count = 0;
};

struct AssemblerEvents {
  std::vector<AssembledFrame> completed;  // in completion order
  std::vector<LostFrame> lost;            // in the order they were given up
};

struct AssemblerStats {
  uint64_t datagrams = 0;
  std::array<uint64_t, kPacketFateCount> packets{};  // indexed by PacketFate
  uint64_t frames_completed = 0;
  uint64_t frames_completed_late = 0;
  std::array<uint64_t, kLossReasonCount> frames_lost{};  // indexed by LossReason
  // Sequence numbers never received (counted once they leave the reorder window, or at flush).
  uint64_t packets_lost = 0;
  // Packets whose sequence number had left the reorder window (counted lost before).
  uint64_t packets_late = 0;
  // Frames completed by forward error correction (some data packets rebuilt from parity), and
  // the data packets rebuilt.
  uint64_t frames_recovered = 0;
  uint64_t packets_recovered = 0;
  // LostFrame reports not queued because 4096 were waiting for poll() (still in frames_lost).
  uint64_t lost_reports_dropped = 0;
  size_t bytes_in_flight = 0;
  size_t peak_bytes_in_flight = 0;
  size_t frames_in_flight = 0;
  size_t peak_frames_in_flight = 0;

  uint64_t count(PacketFate f) const { return packets[size_t(f)]; }
  uint64_t lost(LossReason r) const { return frames_lost[size_t(r)]; }
  uint64_t frames_lost_total() const;
  uint64_t packets_dropped() const;  // every fate but Accepted and Completed
};

// Which sequence numbers of one stream arrived, over a sliding window behind the newest one.
class SequenceTracker {
 public:
  enum class Seen : uint8_t { New, Duplicate, Late };
  explicit SequenceTracker(uint32_t window_packets = 1024);
  // Records `sequence`; adds to `lost` the sequence numbers that this pushes out of the window
  // without having been received.
  Seen on_packet(uint32_t sequence, uint64_t& lost);
  // Sequence numbers between the first and the newest received that are still missing.
  uint64_t missing() const;
  // Counts every missing sequence number as lost and starts over.
  uint64_t flush();
  uint32_t window() const { return window_; }

 private:
  bool test(uint32_t s) const { return (bits_[(s & mask_) >> 6] >> (s & 63)) & 1u; }
  void set(uint32_t s) { bits_[(s & mask_) >> 6] |= uint64_t(1) << (s & 63); }
  void clear(uint32_t s) { bits_[(s & mask_) >> 6] &= ~(uint64_t(1) << (s & 63)); }

  uint32_t window_;
  uint32_t mask_;
  std::vector<uint64_t> bits_;
  bool started_ = false;
  uint32_t highest_ = 0;  // newest sequence number received
  uint32_t floor_ = 0;    // oldest sequence number that counts (the first received)
};

class Assembler {
 public:
  explicit Assembler(AssemblerConfig config = {});
  const AssemblerConfig& config() const { return config_; }

  // Checks and stores one datagram received at `now_ms`. Never throws for any datagram.
  PacketFate push(std::span<const uint8_t> datagram, int64_t now_ms);
  // Gives up frames that timed out by `now_ms`, forgets idle streams, and returns (moves out)
  // the frames completed and lost since the last call.
  AssemblerEvents poll(int64_t now_ms);
  // Gives up every partial frame (Flushed), counts every missing sequence number as lost, and
  // returns the events like poll().
  AssemblerEvents flush(int64_t now_ms);

  const AssemblerStats& stats() const { return stats_; }
  // Sequence numbers currently missing but not yet counted lost (may still arrive).
  uint64_t packets_missing() const;
  size_t streams() const { return streams_.size(); }

 private:
  struct Frame {
    PacketMeta meta;
    uint32_t total_bytes = 0;
    uint16_t count = 0;
    uint16_t chunk_bytes = 0;
    FecLayout fec;          // parity packets and their blocks (fec.parity 0: none)
    uint16_t received = 0;  // data and parity packets
    uint16_t received_data = 0;
    std::vector<uint8_t> bytes;         // the pass; with parity: count shards of the FEC shard size
    std::vector<uint8_t> parity_bytes;  // parity shards, in index order
    std::vector<uint16_t> block_have;   // per FEC block: its packets received
    std::vector<uint64_t> have;         // one bit per packet index
    int64_t first_packet_ms = 0;
    size_t held() const { return bytes.size() + parity_bytes.size(); }
  };
  struct Stream {
    explicit Stream(uint32_t window) : sequence(window) {}
    std::vector<Frame> frames;       // partial frames, at most max_frames_in_flight
    std::vector<uint32_t> finished;  // ring of frame ids recently completed or given up
    size_t finished_next = 0;
    bool any_completed = false;
    uint32_t newest_completed = 0;
    SequenceTracker sequence;
    int64_t last_packet_ms = 0;
  };

  void give_up(Stream& s, size_t frame_index, LossReason reason);
  void report_lost(const LostFrame& lost);
  void remember_finished(Stream& s, uint32_t frame_id);
  bool recently_finished(const Stream& s, uint32_t frame_id) const;
  void complete(Stream& s, size_t frame_index);
  bool rebuild(Frame& f);
  void make_room(size_t bytes);
  void add_in_flight(const Frame& f);
  void remove_in_flight(const Frame& f);
  int64_t advance_clock(int64_t now_ms);

  AssemblerConfig config_;
  std::map<uint32_t, Stream> streams_;  // key: stream id << 8 | pass kind
  AssemblerEvents pending_;
  AssemblerStats stats_;
  int64_t now_ms_ = INT64_MIN;  // the latest time seen (the clock never goes back)
};

}  // namespace dhr
