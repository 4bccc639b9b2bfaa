// The client's side of one pass stream, shared by the simulator (core/frame_loop) and live mode
// (core/live): decodes the pass frames the assembler completes, in order, and keeps the newest;
// then predicts it to the displayed frame.
//
// A gap in the sequence numbers before a completed frame means a frame of the stream was lost:
// a stateful decoder (h264) cannot go on from it, so it is reset and asks for a keyframe; a
// failed decode does the same. A decoder that keeps earlier frames as references (delta:
// Codec::holds() >= 0) is not reset: it asks the server to predict from the newest frame it
// holds (Outcome::holds). A decoder that heals by itself (periodic intra refresh:
// Codec::heals_after_loss) goes on decoding after a gap and asks for nothing; after a failed
// decode it asks for a keyframe only before its first picture or on a second failure in a row.
#pragma once

#include "core/backend/backend.h"
#include "core/buffers/gbuffer.h"
#include "core/net/assembler.h"

#include <memory>
#include <optional>
#include <string>

namespace dhr {

struct PassReceiver {
  std::unique_ptr<Codec> codec;
  uint32_t expected_sequence = 0;
  int frame = -1;         // the newest decoded server frame (-1: none yet)
  int failed_in_row = 0;  // decodes failed since the last one that worked
  PassBuffer buffer;      // its decoded buffer

  struct Outcome {
    bool decoded = false;  // decoded (and kept when newer than `frame`)
    bool decode_error = false;
    bool gap_reset = false;         // a lost frame before this one: the decoder was reset, or
                                    // (one that keeps references) asked to recover
    bool keyframe_request = false;  // the decoder needs a keyframe (it was reset after a gap or
                                    // an error), or a frame predicted from `holds`
    int holds = -1;                 // with keyframe_request: the newest frame the decoder holds
    double decode_ms = 0.0;         // wall time of the decode call
  };
  // Decodes `f` (its encoded bytes are consumed); `context`: what the client knows of its frame.
  Outcome on_frame(AssembledFrame& f, const FrameContext& context = {});
};

}  // namespace dhr
