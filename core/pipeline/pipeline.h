// The server's and the client's stage sequences, used by both the virtual-clock simulator
// (core/sim/frame_loop.h) and live mode (core/live/live.h), so that both run the same stages on the
// same data (docs/architecture.md has the picture):
//
//   ServerPipeline::run   rasterize -> trace (cached by the caller) -> denoise -> [remote:
//                         composite] -> encode -> packetize, per pass of the list, with the
//                         wall time of every stage
//   ClientPipeline        receive (decode each completed pass frame) ... display: predict each
//                         pass's newest buffer to the displayed frame -> composite
//   LocalReference        the client's ideal: this frame's own passes, denoised by a sequence of
//                         its own, composited; what every displayed frame is scored against
//
// The callers keep only what differs: the simulator its clock, links and server schedule; live
// mode its sockets and handshake.
#pragma once

#include "core/backend/backend.h"
#include "core/base/stream_dump.h"
#include "core/buffers/camera.h"
#include "core/buffers/gbuffer.h"
#include "core/buffers/image.h"
#include "core/buffers/upsample.h"
#include "core/config/run_plan.h"
#include "core/config/run_config.h"
#include "core/net/assembler.h"
#include "core/pass/passes.h"
#include "core/pipeline/pass_receiver.h"
#include "core/raster/raster.h"
#include "core/scene/scene.h"
#include "core/trace/trace.h"

#include <deque>
#include <functional>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <vector>

namespace dhr {

class RtScene;

// The traced passes of frame `frame` for G-buffer `gbuf` (a cache lookup, or a trace).
using TraceFn = std::function<std::shared_ptr<const TracedPasses>(uint32_t frame, const GBuffer& gbuf)>;
// Traces with `rt` and no cache.
TraceFn direct_tracer(RtScene& rt, const RunPlan& plan);

// The server's G-buffer of a frame and the wall time its rasterization took: rasterized now,
// or one the simulator's client already rasterized for the same RasterFrame (then `ms` is that
// rasterization's time, so the server's stage time still says what the work costs).
struct Rastered {
  std::shared_ptr<const GBuffer> gbuf;
  double ms = 0.0;
};
using RasterFn = std::function<Rastered(const RasterFrame& frame)>;
// Rasterizes `frame` now.
Rastered rasterize_now(const RasterFrame& frame);

// The scale at which `desc` is a reduced-resolution pass of `gbuf` (1: the same size); dhr::Error
// when it is none (core/buffers/upsample.h).
int reduced_scale(const GBuffer& gbuf, const PassDesc& desc);

// The wall time of one stage (ms).
struct StageTime {
  const char* name;
  double ms;
};

// One traced pass of one frame after its denoisers, and the wall time they took then.
struct DenoisedPass {
  PassBuffer buffer;
  double ms = 0.0;
};

// Where denoised passes are kept for other runs (the simulator's TraceCache): a temporal
// denoiser's output depends on nothing but its settings, the pass's trace settings and the
// sequence of frames it was fed, so the runs of a sweep whose servers (or local references)
// feed the same sequence compute it once (docs/performance.md, "Computed once per sweep").
class DenoiseMemo {
 public:
  virtual ~DenoiseMemo() = default;
  virtual std::shared_ptr<const DenoisedPass> find(const std::string& key) = 0;
  virtual void insert(const std::string& key, std::shared_ptr<const DenoisedPass> value) = 0;
  // Holds `key` for this caller while the handle lives, so that runs side by side compute it
  // once (TraceCache::Claim); null: the memo has no other users.
  virtual std::shared_ptr<void> claim(const std::string& key) = 0;
};

// How a DenoiseStage shares its outputs through a memo.
struct DenoiseSharing {
  DenoiseMemo* memo = nullptr;
  // Per traced pass: all its denoised buffers depend on besides the frame sequence (the scene,
  // camera path, the pass's trace settings and its denoiser); empty: not shared.
  std::vector<std::string> pass_keys;
  // A frame's G-buffer and traced passes again: a run that took outputs from the memo and then
  // feeds a frame the memo lacks first feeds its denoisers the frames it skipped (same bits).
  RasterFn raster;
  TraceFn trace;
};

// The denoisers of one side: each 8-bit plane of a traced pass (plan.traced) through its pass's
// denoiser (AO: one; soft visibility: one per light, each with its own history). Bitmasks are
// never denoised.
class DenoiseStage {
 public:
  DenoiseStage(const RunPlan& plan, const Registries& registries);
  // Shares the temporal denoisers' outputs through `sharing.memo` from now on (before the first
  // frame).
  void share(DenoiseSharing sharing);
  // Denoises `traced` (traced pass `pass` of the list given to the constructor; frame `frame`,
  // whose G-buffer `gbuf` was rasterized for `raster`) into `out`, whose full scale becomes the
  // denoiser's output scale (a pass without denoisers: a copy). Returns the denoisers' wall time
  // (taken from the memo: the time they took when computed).
  double run(const RasterFrame& raster, const GBuffer& gbuf, uint32_t frame, size_t pass, const PassBuffer& traced,
             PassBuffer& out);
  // True when a denoiser keeps history: then every frame must go through it, in order.
  bool keeps_history() const;

 private:
  // A frame a shared pass took from the memo, not yet fed to its denoisers.
  struct Skipped {
    uint32_t frame;
    RasterFrame raster;
  };
  // A shared pass's sequence so far: its memo key is base + the frames fed, as ranges (key()).
  struct Chain {
    std::string base, closed;       // closed: the ranges before the open one
    int64_t first = -1, last = -1;  // the open range (first = -1: none)
    double last_time_s = 0.0;       // the scene time of the last frame fed
    std::vector<Skipped> skipped;
    std::string open_range() const;
    std::string key() const;
    void append(uint32_t frame, const RasterFrame& raster);
  };
  void feed(const GBuffer& gbuf, uint32_t frame, size_t pass, PassBuffer& buffer);
  void catch_up(size_t pass);
  std::vector<std::vector<std::unique_ptr<Denoiser>>> planes_;  // per traced pass: per 8-bit plane
  std::vector<std::string> names_;                              // per traced pass
  DenoiseSharing sharing_;
  std::vector<std::optional<Chain>> chains_;  // per traced pass: when shared
};

// ---- server

struct SentPass {
  std::string name;
  PassDesc desc;
  size_t encoded_bytes = 0;
  std::vector<std::vector<uint8_t>> packets;  // ready to send, in order
};

struct ServerFrame {
  uint32_t frame = 0;
  std::vector<SentPass> passes;   // in the order of ServerPipeline::passes()
  TraceStats trace;               // of this frame's trace (its wall time: when it was traced)
  std::vector<StageTime> stages;  // every stage run, in order ("encode" once per pass)
  double compute_ms = 0.0;        // their sum
};

class ServerPipeline {
 public:
  // `stream_id` goes into every packet header (the simulator: 0; live mode: the session's).
  // `raster`: where the server's G-buffers come from (null: rasterize_now).
  // `plan` must outlive the pipeline.
  ServerPipeline(const RunPlan& plan, const Registries& registries, TraceFn trace, uint16_t stream_id,
                 RasterFn raster = nullptr);
  const std::vector<PlannedPass>& passes() const { return plan_.sent; }
  // The sequence number of the next packet of pass `pass` (0 at the start; live mode starts
  // each session's streams at random numbers).
  void set_next_sequence(size_t pass, uint32_t sequence) { sequence_.at(pass) = sequence; }
  // Everything the server does for client frame `frame`, seen from `camera` at scene time
  // `time_s`. The previous call's camera gives the motion vectors. `keyframe`: the client
  // asked for one after a loss; `client_holds`: per sent pass, the newest frame its decoder
  // still holds when that pass reported the loss (-1: not reported; empty: none).
  ServerFrame run(uint32_t frame, const Camera& camera, double time_s, bool keyframe,
                  std::span<const int> client_holds = {});
  // The stream's bit budget from the next frame on (kbit/s; the adaptive bitrate controller's
  // rate): replaces stream_kbps, which it must be set with (plan_run checks that).
  void set_stream_kbps(double kbps) { stream_kbps_ = kbps; }
  // Shares its denoisers' outputs through `memo` (DenoiseStage::share; `pass_keys` per traced
  // pass), feeding skipped frames again through its own raster and trace functions.
  void share_denoised(DenoiseMemo* memo, std::vector<std::string> pass_keys) {
    denoise_.share({memo, std::move(pass_keys), raster_, trace_});
  }

 private:
  void dump(size_t pass, const PassDesc& desc, uint32_t frame, std::span<const uint8_t> encoded);
  const RunPlan& plan_;
  const SimConfig& c_;  // plan_.config
  TraceFn trace_;
  RasterFn raster_;
  uint16_t stream_id_;
  DenoiseStage denoise_;
  std::vector<std::unique_ptr<Codec>> codecs_;  // per sent pass
  std::vector<uint32_t> codec_ids_, sequence_;
  std::vector<std::unique_ptr<StreamDump>> dumps_;  // per sent pass, when config.dump_streams_dir is set
  bool has_prev_ = false;
  Camera prev_camera_;
  double prev_time_s_ = 0.0;
  // The G-buffers of the last frames, kept when a codec predicts through them
  // (Codec::gbuffers_referenced; 0: none kept).
  int gbuffers_kept_ = 0;
  std::deque<std::pair<uint32_t, std::shared_ptr<const GBuffer>>> gbuffers_;
  int depth_pass_ = -1;  // remote mode: the depth pass's index in plan_.sent, when one is sent
  // stream_kbps: per sent pass, whether its codec takes the budget's share; the wire bytes of
  // every sent pass over the last second of frames.
  std::vector<bool> budgeted_;
  double stream_kbps_ = 0.0;  // stream_kbps, or the rate set_stream_kbps gave
  std::deque<std::vector<size_t>> wire_history_;
  double budget_share_kbps() const;
};

// ---- client

struct ClientFrame {
  ImageRGB8 image;
  std::vector<int> source_frame;      // per pass: the server frame displayed (-1: none)
  std::vector<uint64_t> disoccluded;  // per pass: the predictor's count
  std::vector<bool> without_data;     // per pass: shown with its local fallback (nothing usable)
  int passes_without_data = 0;        // how many passes were
  double predict_ms = 0.0, composite_ms = 0.0;
  double upsample_ms = 0.0;  // passes traced at reduced resolution (once per received frame)
  bool composited = false;   // false: a colour frame shown as it is (remote)
};

class ClientPipeline {
 public:
  // `plan` must outlive the pipeline.
  ClientPipeline(const RunPlan& plan, const Registries& registries);
  const std::vector<PlannedPass>& passes() const { return plan_.sent; }
  // Whether a pass comes at reduced resolution (then display upsamples it: ClientFrame::upsample_ms).
  bool upsamples() const;
  // The pass a received frame of `kind` belongs to (-1: none of this run's).
  int pass_of(PassKind kind) const;
  // Decodes one completed frame of pass `pass` (its bytes are consumed), with the G-buffers the
  // client keeps as the decoder's context (FrameContext).
  PassReceiver::Outcome receive(int pass, AssembledFrame& frame);
  const PassReceiver& receiver(int pass) const { return receivers_[size_t(pass)]; }
  PassReceiver& receiver(int pass) { return receivers_[size_t(pass)]; }
  // The hybrid client keeps its G-buffers (the last history_frames) for prediction.
  void keep(int frame, std::shared_ptr<const GBuffer> gbuf);
  const GBuffer* gbuffer(int frame) const;
  // The displayed image of client frame `frame` with G-buffer `gbuf`: every pass's newest
  // buffer predicted to it, composited (remote: the colour frame warped from the camera the
  // server rendered it for, `source_camera_of(its frame)`, to gbuf.camera; nothing received
  // yet: black). A pass with nothing usable (none received, or its G-buffer no longer kept)
  // takes its local fallback: fully lit, AO 1.
  ClientFrame display(int frame, const GBuffer& gbuf, const std::function<Camera(int)>& source_camera_of);

 private:
  const RunPlan& plan_;
  const SimConfig& c_;  // plan_.config
  UpsampleFilter filter_;
  std::vector<PassReceiver> receivers_;
  std::vector<std::unique_ptr<Predictor>> predictors_;
  std::deque<std::pair<int, std::shared_ptr<const GBuffer>>> history_;
  // Per pass traced at reduced resolution: its newest received frame, upsampled (and which).
  std::vector<std::pair<int, PassBuffer>> upsampled_;
  int depth_pass_ = -1;  // remote mode: the depth pass's index, when one is sent
  // Remote mode: what the client knows of the colour frame it shows (its camera, and its depth
  // when that frame's depth pass arrived), unpacked once per received frame, not per display.
  GBuffer remote_src_;
  int remote_src_frame_ = -1;
  bool remote_src_has_depth_ = false;
};

// The local reference: what the client would show with zero latency and lossless passes.
class LocalReference {
 public:
  // `plan` must outlive it.
  LocalReference(const RunPlan& plan, const Registries& registries);
  // Whether frame `frame` must be fed although its image is not wanted (a temporal denoiser).
  bool needs_every_frame() const { return denoise_.keeps_history(); }
  // Denoises frame `frame`'s traced passes in sequence (`gbuf` rasterized for `raster`); returns
  // the composite when `want_image`.
  std::optional<ImageRGB8> frame(uint32_t frame, const RasterFrame& raster, const GBuffer& gbuf,
                                 const TracedPasses& traced, bool want_image);
  // Shares its denoisers' outputs (DenoiseStage::share).
  void share_denoised(DenoiseSharing sharing) { denoise_.share(std::move(sharing)); }

 private:
  const RunPlan& plan_;
  DenoiseStage denoise_;
  UpsampleFilter filter_;
};

}  // namespace dhr
