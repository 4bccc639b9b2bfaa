#include "core/pipeline/pass_receiver.h"

#include <chrono>

namespace dhr {

PassReceiver::Outcome PassReceiver::on_frame(AssembledFrame& f, const FrameContext& context) {
  Outcome o;
  const bool gap = expected_sequence != f.meta.first_sequence;
  // The next frame of the stream starts after this one's data and parity packets.
  expected_sequence = f.meta.first_sequence + f.packet_count + f.parity_count;
  // Asks for recovery: from the newest frame the decoder holds, else a keyframe after a reset.
  auto request = [&] {
    o.keyframe_request = true;
    o.holds = codec->holds();
    if (o.holds < 0) codec->reset();
  };
  if (gap && codec->stateful() && frame >= 0 && !codec->heals_after_loss()) {
    request();
    o.gap_reset = true;
  }
  PassBuffer out;
  std::string error;
  const auto t0 = std::chrono::steady_clock::now();
  const bool ok = codec->decode_in_context(f.encoded, f.meta.desc, context, out, error);
  o.decode_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  if (!ok) {
    o.decode_error = true;
    // A decoder that heals by itself may drop a picture around a gap (libavcodec's H.264 holds
    // back one whose order count the lost frame disturbed) and go on: it asks for a keyframe
    // only when it has decoded nothing yet (the stream's headers came with a lost frame) or
    // fails twice in a row.
    ++failed_in_row;
    if (codec->stateful() && (!codec->heals_after_loss() || frame < 0 || failed_in_row >= 2)) request();
    return o;
  }
  failed_in_row = 0;
  o.decoded = true;
  if (int(f.meta.frame_id) > frame) {
    frame = int(f.meta.frame_id);
    buffer = std::move(out);
  }
  return o;
}

}  // namespace dhr
