// The three backend interfaces (codec, denoiser, predictor) and the registry that creates
// them by name. A backend is one .cpp in backends/<kind>/ that defines a function returning
// its BackendEntry; backends/register_all.cpp holds one explicit line per backend (no static
// constructors, which a linker may drop from a static library).
#pragma once

#include "core/base/error.h"
#include "core/base/params.h"
#include "core/buffers/gbuffer.h"
#include "core/buffers/image.h"
#include "core/buffers/pass_buffer.h"

#include <nlohmann/json.hpp>

#include <cstdint>
#include <functional>
#include <memory>
#include <span>
#include <string>
#include <vector>

namespace dhr {

// ---- Codec: compresses one pass of one frame. Stateful codecs (video) keep state between
// frames; reset() returns them to their initial state.
// What one end knows about the frame a pass buffer was made for, beside the buffer: the frame's
// index and this end's G-buffer of it (the server's for the camera it traced; the client's own
// rasterization of that camera: the two agree exactly), and the G-buffers of earlier frames
// this end still keeps. Codecs that predict from what the client already holds (delta with a
// predictor) need it; the others ignore it.
struct FrameContext {
  uint32_t frame = 0;
  const GBuffer* gbuf = nullptr;                       // null: not available
  std::function<const GBuffer*(uint32_t)> gbuffer_of;  // null or a null result: not kept
};

struct EncodeOptions {
  bool force_keyframe = false;
  FrameContext context;
  // After the client reported a loss: the newest frame of this stream its decoder still holds
  // (Codec::holds(); -1: none or not reported). A codec that keeps references predicts from
  // that frame instead of sending a keyframe.
  int client_holds = -1;
  // A bit budget's share for this pass (kbit/s; 0: the codec's own rate). Only a codec whose
  // takes_target_kbps() is true uses it; it may change from frame to frame.
  double target_kbps = 0.0;

  static EncodeOptions keyframe(bool force = true) {
    EncodeOptions o;
    o.force_keyframe = force;
    return o;
  }
};

class Codec {
 public:
  virtual ~Codec() = default;
  virtual bool lossless() const = 0;
  // True when decoding a frame needs the frames before it (P-frames): after a lost frame the
  // receiver resets its decoder and asks the sender for a keyframe.
  virtual bool stateful() const { return false; }
  // True when this codec follows EncodeOptions::target_kbps frame by frame (a stream's bit
  // budget, stream_kbps, is shared among such passes).
  virtual bool takes_target_kbps() const { return false; }
  // Empty when this codec can carry buffers of `desc` (bit-exactly if lossless()); else the
  // reason it refuses them (a lossy codec refuses a bitmask).
  virtual std::string refuses(const PassDesc& desc) const {
    (void)desc;
    return {};
  }
  virtual void encode(const PassBuffer& in, const EncodeOptions& options, std::vector<uint8_t>& out) = 0;
  // Expected failures (corrupt or foreign bytes) return false with `error` set; `out` is then
  // unspecified. Never crashes, never returns true with wrong-sized output.
  virtual bool decode(std::span<const uint8_t> in, const PassDesc& desc, PassBuffer& out, std::string& error) = 0;
  // decode() with what the client knows about the frame; what the receivers call. Codecs that
  // use the context override this one.
  virtual bool decode_in_context(std::span<const uint8_t> in, const PassDesc& desc, const FrameContext& context,
                                 PassBuffer& out, std::string& error) {
    (void)context;
    return decode(in, desc, out, error);
  }
  // How many earlier frames' G-buffers encode() may ask FrameContext::gbuffer_of for (the
  // server keeps that many; 0: it uses no context).
  virtual int gbuffers_referenced() const { return 0; }
  // A decoder that keeps earlier frames as references: the newest frame it holds decoded (-1:
  // none, or no such codec). After a loss the receiver does not reset such a decoder; it reports
  // this frame and the encoder predicts from it (EncodeOptions::client_holds).
  virtual int holds() const { return -1; }
  // A stateful decoder that goes on after a lost frame, showing the error until the stream
  // heals by itself (periodic intra refresh): the receiver neither resets it nor asks for a
  // keyframe after a gap (it still does after a failed decode).
  virtual bool heals_after_loss() const { return false; }
  virtual void reset() {}
  // The standard stream that this codec's encode() outputs make, one after the other, as a file
  // extension: "h264" or "hevc" (Annex B byte streams), "ivf" (AV1 temporal units, each behind
  // an IVF frame header: core/base/stream_dump.h); empty when the bytes are no standard stream.
  virtual std::string stream_format() const { return {}; }
};

// ---- Denoiser: server-side filtering of a noisy 8-bit signal (AO counts, or one light's
// soft visibility), guided by the server's G-buffer of the same frame.
struct DenoiseInput {
  const GBuffer& gbuf;        // the G-buffer the noisy values were traced for
  const ImageU8& noisy;       // values 0..full_scale
  int full_scale = 255;       // the value that means 1.0 (N rays for raw AO counts)
  uint32_t frame = 0;         // server frame index
  bool history_valid = true;  // false on a camera cut or after skipped/lost frames: reset history
};

class Denoiser {
 public:
  virtual ~Denoiser() = default;
  // Writes `out` at the input's size with values 0..output_full_scale(in.full_scale).
  virtual void denoise(const DenoiseInput& in, ImageU8& out) = 0;
  virtual void reset() = 0;
  // The value that means 1.0 in the output for an input whose 1.0 is `input_full_scale`: 255
  // for a filter; the input's own scale for one that passes the values through (none: the
  // paper sends the raw counts).
  virtual int output_full_scale(int input_full_scale) const {
    (void)input_full_scale;
    return 255;
  }
  // True when the output depends on earlier frames (a temporal filter): callers must then run
  // it on every frame in order; false lets them skip frames whose output they do not need.
  virtual bool keeps_history() const { return true; }
};

// ---- Predictor: turns the newest received server buffer (computed for an older client frame)
// into a buffer for the frame being displayed.
// The remote client has no G-buffers: there `src` and `dst` carry the cameras only, and
// `src.depth` the depth the server sent with the colour frame (empty when the predictor does not
// read depth, or that frame's depth pass did not arrive).
struct PredictInput {
  const PassBuffer& received;  // decoded server buffer for frame `src`
  const GBuffer& src;          // the client's G-buffer of the frame the server traced
  const GBuffer& dst;          // the client's G-buffer of the frame being displayed
};

struct PredictStats {
  uint64_t pixels = 0;       // covered pixels predicted
  uint64_t disoccluded = 0;  // pixels with no valid source sample (filled by the stated rule)
};

class Predictor {
 public:
  virtual ~Predictor() = default;
  virtual PredictStats predict(const PredictInput& in, PassBuffer& out) = 0;
  virtual void reset() {}
  // True when the per-pixel work does not depend on the pass and the predictor keeps no state
  // (reprojection: the source taps): then predict_passes on one instance gives several passes
  // received for the same frame what their own instances, of the same settings, would give, and
  // does the shared work once. The client groups its passes that way (core/pipeline/pipeline.cpp).
  virtual bool predicts_passes_together() const { return false; }
  // Predicts `received[i]` into `out[i]` (every buffer of src's size, each as predict would)
  // and returns each one's stats; by default one predict call per pass.
  virtual std::vector<PredictStats> predict_passes(const GBuffer& src, const GBuffer& dst,
                                                   std::span<const PassBuffer* const> received,
                                                   std::span<PassBuffer* const> out) {
    std::vector<PredictStats> stats;
    for (size_t i = 0; i < received.size(); ++i) stats.push_back(predict({*received[i], src, dst}, *out[i]));
    return stats;
  }
  // A remote client's colour predictor that reprojects with the server's depth: the bits of
  // inverse depth it asks for (8..16); remote mode then sends a depth pass of that precision
  // beside the colour (its bytes counted; core/buffers/depth_pass.h). 0: it reads no depth.
  virtual int depth_bits() const { return 0; }
};

// ---- Registry
template <class Interface>
struct BackendEntry {
  std::string name;
  std::string description;  // one line
  std::vector<ParamSpec> params;
  std::function<std::unique_ptr<Interface>(const Params&)> create;
};

using CodecEntry = BackendEntry<Codec>;
using DenoiserEntry = BackendEntry<Denoiser>;
using PredictorEntry = BackendEntry<Predictor>;

template <class Interface>
class Registry {
 public:
  explicit Registry(std::string kind) : kind_(std::move(kind)) {}
  const std::string& kind() const { return kind_; }

  void add(BackendEntry<Interface> entry) {
    if (find(entry.name)) fail("{} backend '{}' is registered twice", kind_, entry.name);
    entries_.push_back(std::move(entry));
  }
  const BackendEntry<Interface>* find(const std::string& name) const {
    for (const auto& e : entries_)
      if (e.name == name) return &e;
    return nullptr;
  }
  // Throws dhr::Error naming the valid backends when `name` is unknown.
  const BackendEntry<Interface>& get(const std::string& name) const {
    if (const auto* e = find(name)) return *e;
    fail("unknown {} '{}' (valid: {})", kind_, name, names_text());
  }
  // Validates parameters, then creates. Throws dhr::Error on any problem.
  std::unique_ptr<Interface> create(const std::string& name, const nlohmann::json& params,
                                    Params* effective = nullptr) const {
    const auto& e = get(name);
    Params p(kind_ + " '" + name + "'", e.params, params);
    if (effective) *effective = p;
    return e.create(p);
  }
  const std::vector<BackendEntry<Interface>>& entries() const { return entries_; }
  std::string names_text() const {
    std::string s;
    for (const auto& e : entries_) s += (s.empty() ? "" : ", ") + e.name;
    return s;
  }

 private:
  std::string kind_;
  std::vector<BackendEntry<Interface>> entries_;
};

struct Registries {
  Registry<Codec> codecs{"codec"};
  Registry<Denoiser> denoisers{"denoiser"};
  Registry<Predictor> predictors{"predictor"};
};

}  // namespace dhr
