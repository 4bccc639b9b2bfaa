// Pass coding against what the client holds (backends/codec/delta.cpp with predictor
// reprojection; docs/architecture.md, "Pass coding against what the client holds"): the server
// and the client predict a frame from a reference both hold, through G-buffers both rasterize,
// and only the residual travels.
//
// The G-buffers here are real (the room scene rasterized along its camera path); the passes
// are patterns fixed to the world (a function of each pixel's world position), so a perfect
// reprojection predicts them everywhere except where a surface comes into view. That makes the
// savings a property of the prediction, and every decode is checked bit for bit.
#include "backends/register_all.h"
#include "core/raster/raster.h"
#include "core/scene/scene_load.h"
#include "tests/support_buffers.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <map>

namespace dhr {
namespace {

using nlohmann::json;

constexpr int kW = 160, kH = 90;

const Scene& room() {
  static const Scene s = load_scene(std::string(DHR_SOURCE_DIR) + "/scenes/room.json", SceneSearchPath::standard());
  return s;
}

double time_of(int frame) { return 1.0 + frame / 60.0; }

// The client's (and the server's: they agree exactly) G-buffer of `frame`, the camera panning
// `speed` times as fast as the scene's path.
const GBuffer& gbuffer(int frame, double speed = 1.0) {
  static std::map<std::pair<int, double>, GBuffer> kept;
  auto it = kept.find({frame, speed});
  if (it == kept.end()) {
    const double t = 1.0 + speed * (time_of(frame) - 1.0), t_prev = 1.0 + speed * (time_of(frame - 1) - 1.0);
    GBuffer g;
    rasterize({&room(), room().camera.at(t, kW, kH), t, room().camera.at(t_prev, kW, kH), t_prev}, g);
    it = kept.emplace(std::pair{frame, speed}, std::move(g)).first;
  }
  return it->second;
}

FrameContext context(int frame, double speed = 1.0) {
  return {uint32_t(frame), &gbuffer(frame, speed), [speed](uint32_t f) { return &gbuffer(int(f), speed); }};
}

std::unique_ptr<Codec> delta(const std::string& predictor, int keyframe_interval = 1000, int references = 8) {
  return registries().codecs.create("delta", {{"inner", "zstd"},
                                              {"predictor", predictor},
                                              {"keyframe_interval", keyframe_interval},
                                              {"references", references}});
}

std::vector<uint8_t> encode(Codec& c, const PassBuffer& in, int frame, int client_holds = -1, double speed = 1.0) {
  EncodeOptions o;
  o.context = context(frame, speed);
  o.client_holds = client_holds;
  std::vector<uint8_t> out;
  c.encode(in, o, out);
  return out;
}

uint32_t reference_of(const std::vector<uint8_t>& bytes) {
  return uint32_t(bytes[5]) | uint32_t(bytes[6]) << 8 | uint32_t(bytes[7]) << 16 | uint32_t(bytes[8]) << 24;
}

TEST(PassCoding, ReprojectedDeltaIsExactAndSmallerThanThePlainDelta) {
  for (PassKind kind : {PassKind::Ao, PassKind::Visibility}) {
    for (double speed : {1.0, 4.0}) {
      std::map<std::string, size_t> bytes;
      for (const std::string predictor : {"none", "reprojection"}) {
        auto enc = delta(predictor), dec = delta(predictor);
        for (int f = 0; f < 12; ++f) {
          const PassBuffer in = test::make_world_pass(gbuffer(f, speed), kind);
          const std::vector<uint8_t> coded = encode(*enc, in, f, -1, speed);
          if (f > 0) bytes[predictor] += coded.size();  // after the keyframe
          PassBuffer out;
          std::string error;
          ASSERT_TRUE(dec->decode_in_context(coded, in.desc, context(f, speed), out, error)) << error;
          ASSERT_EQ(out.bytes, in.bytes) << predictor << " frame " << f;
        }
      }
      std::printf("%s, pan x%.0f: delta %zu B, delta + reprojection %zu B over 11 frames\n", pass_kind_name(kind),
                  speed, bytes["none"], bytes["reprojection"]);
      // Sub-pixel motion resamples the pattern, so even an exact reprojection leaves a residual
      // (bilinear on 8-bit passes; bitmask edges cannot be interpolated): smaller, not zero.
      EXPECT_LT(bytes["reprojection"], bytes["none"])
          << pass_kind_name(kind) << ": a pattern fixed to the world should be predicted better by reprojection";
    }
  }
}

// Frames 0..frames-1 of the world-fixed AO pass with frame 3 lost on the link: frame 4 (predicted
// from it) must be refused, the decoder then reports holding frame 2, the server is told so for
// frame 5, whose recovery frame is a delta from frame 2; `check(f, in, out)` checks every frame
// that decodes (all but 3 and 4 must).
template <class Check>
void lose_frame_3_and_recover(Codec& enc, Codec& dec, int frames, Check check) {
  int holds = -1;
  for (int f = 0; f < frames; ++f) {
    const PassBuffer in = test::make_world_pass(gbuffer(f), PassKind::Ao);
    const std::vector<uint8_t> coded = encode(enc, in, f, f == 5 ? holds : -1);
    if (f == 3) continue;  // lost on the link
    PassBuffer out;
    std::string error;
    const bool ok = dec.decode_in_context(coded, in.desc, context(f), out, error);
    if (f == 4) {
      EXPECT_FALSE(ok) << "frame 4 is predicted from the lost frame 3";
      EXPECT_NE(error.find("needs frame 3"), std::string::npos) << error;
      holds = dec.holds();
      EXPECT_EQ(holds, 2);
      continue;
    }
    ASSERT_TRUE(ok) << "frame " << f << ": " << error;
    check(f, in, out);
    if (f == 5) {
      EXPECT_EQ(coded[0], 'D') << "the recovery frame is a delta, not a keyframe";
      EXPECT_EQ(reference_of(coded), 2u) << "predicted from the frame the client holds";
    }
  }
}

// A lost frame: the decoder keeps its references; the server, told which frame the client holds,
// predicts the next frame from that one instead of sending a keyframe.
TEST(PassCoding, LossRecoversFromTheFrameTheClientHolds) {
  auto enc = delta("reprojection"), dec = delta("reprojection");
  lose_frame_3_and_recover(*enc, *dec, 8, [](int f, const PassBuffer& in, const PassBuffer& out) {
    EXPECT_EQ(out.bytes, in.bytes) << "frame " << f;
  });
}

// The server no longer keeps the frame the client holds (references = 2): a keyframe.
TEST(PassCoding, AHeldFrameTheServerNoLongerKeepsGivesAKeyframe) {
  auto enc = delta("reprojection", 1000, 2), dec = delta("reprojection", 1000, 2);
  for (int f = 0; f < 6; ++f) {
    const PassBuffer in = test::make_world_pass(gbuffer(f), PassKind::Ao);
    const std::vector<uint8_t> coded = encode(*enc, in, f, f == 5 ? 1 : -1);
    if (f == 5) {
      EXPECT_EQ(coded[0], 'K');
    }
    if (f >= 2 && f <= 4) continue;  // lost: the client still holds frames 0 and 1
    PassBuffer out;
    std::string error;
    ASSERT_TRUE(dec->decode_in_context(coded, in.desc, context(f), out, error)) << "frame " << f << ": " << error;
    EXPECT_EQ(out.bytes, in.bytes);
  }
}

// Prediction through G-buffers the two ends do not share must fail, never yield wrong bytes.
TEST(PassCoding, DisagreeingGBuffersGiveADecodeErrorNotWrongBytes) {
  auto enc = delta("reprojection"), dec = delta("reprojection");
  for (int f = 0; f < 2; ++f) {
    const PassBuffer in = test::make_world_pass(gbuffer(f), PassKind::Ao);
    const std::vector<uint8_t> coded = encode(*enc, in, f);
    // The client's G-buffers come from another camera path (4x the pan; frame 0 is the same).
    PassBuffer out;
    std::string error;
    const bool ok = dec->decode_in_context(coded, in.desc, context(f, 4.0), out, error);
    if (f == 0) {
      EXPECT_TRUE(ok) << "a keyframe needs no prediction: " << error;
      continue;
    }
    EXPECT_FALSE(ok) << "frame " << f << " decoded through the wrong G-buffers";
    EXPECT_NE(error.find("CRC-32C"), std::string::npos) << error;
  }
}

TEST(PassCoding, MissingContextIsAClearError) {
  auto enc = delta("reprojection");
  const PassBuffer in = test::make_world_pass(gbuffer(0), PassKind::Ao);
  std::vector<uint8_t> out;
  try {
    enc->encode(in, {}, out);
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("needs the frame's G-buffer"), std::string::npos) << e.what();
  }
  // The decoder: a delta frame without the client's G-buffers is refused.
  auto enc2 = delta("reprojection"), dec = delta("reprojection");
  std::vector<std::vector<uint8_t>> coded;
  for (int f = 0; f < 2; ++f) coded.push_back(encode(*enc2, test::make_world_pass(gbuffer(f), PassKind::Ao), f));
  PassBuffer decoded;
  std::string error;
  ASSERT_TRUE(dec->decode_in_context(coded[0], in.desc, context(0), decoded, error)) << error;
  EXPECT_FALSE(dec->decode(coded[1], in.desc, decoded, error));
  EXPECT_NE(error.find("G-buffers of both frames are needed"), std::string::npos) << error;
  // Colour is refused by name.
  EXPECT_NE(delta("reprojection")->refuses({PassKind::Colour, kW, kH, 3, 255}).find("colour"), std::string::npos);
}

// ---- delta_video: the residual through a lossy video coder, the reference being what the
// client reconstructs (backends/codec/delta_video.cpp).

std::unique_ptr<Codec> delta_video(const std::string& predictor, int crf = 23) {
  return registries().codecs.create("delta_video", {{"inner", "h264"}, {"crf", crf}, {"predictor", predictor}});
}

// Every frame decodes (so the client's reconstruction is the encoder's, bit for bit: its CRC-32C
// is in the header), quality does not drift over the sequence, and reprojection saves bits over
// taking the reference as it is. Printed beside them: plain h264 at the same crf.
TEST(PassCoding, LossyDeltaDecodesToTheEncodersReconstructionWithoutDrift) {
  constexpr int kFrames = 24;
  for (double speed : {1.0, 4.0}) {
    std::map<std::string, size_t> bytes;
    std::map<std::string, double> worst_psnr;
    for (const std::string scheme : {"none", "reprojection", "h264"}) {
      auto enc = scheme == "h264" ? registries().codecs.create("h264", {{"crf", 23}}) : delta_video(scheme);
      auto dec = scheme == "h264" ? registries().codecs.create("h264", {{"crf", 23}}) : delta_video(scheme);
      worst_psnr[scheme] = 1e9;
      for (int f = 0; f < kFrames; ++f) {
        const PassBuffer in = test::make_world_pass(gbuffer(f, speed), PassKind::Ao);
        const std::vector<uint8_t> coded = encode(*enc, in, f, -1, speed);
        if (f > 0) bytes[scheme] += coded.size();
        PassBuffer out;
        std::string error;
        ASSERT_TRUE(dec->decode_in_context(coded, in.desc, context(f, speed), out, error))
            << scheme << " frame " << f << ": " << error;
        worst_psnr[scheme] = std::min(worst_psnr[scheme], test::buffer_psnr_db(in, out));
      }
    }
    std::printf(
        "AO pan x%.0f, crf 23, %d frames after the keyframe: delta_video %zu B (worst %.1f dB), "
        "delta_video + reprojection %zu B (worst %.1f dB), h264 %zu B (worst %.1f dB)\n",
        speed, kFrames - 1, bytes["none"], worst_psnr["none"], bytes["reprojection"], worst_psnr["reprojection"],
        bytes["h264"], worst_psnr["h264"]);
    EXPECT_LT(bytes["reprojection"], bytes["none"]) << "pan x" << speed;
    // No drift: the worst frame of the prediction chain stays near plain h264's worst.
    EXPECT_GT(worst_psnr["reprojection"], worst_psnr["h264"] - 3.0) << "pan x" << speed;
    EXPECT_GT(worst_psnr["reprojection"], 30.0) << "pan x" << speed;
  }
}

// A lost frame: the inner stream cannot go on, but the client's reconstructions can; the server,
// told which one the client holds, predicts from it and restarts the inner stream.
TEST(PassCoding, LossyDeltaRecoversFromTheReconstructionTheClientHolds) {
  auto enc = delta_video("reprojection"), dec = delta_video("reprojection");
  lose_frame_3_and_recover(*enc, *dec, 9, [](int f, const PassBuffer& in, const PassBuffer& out) {
    EXPECT_GT(test::buffer_psnr_db(in, out), 30.0) << "frame " << f;
  });
  // Without the recovery (the server never heard of the loss), the frames after the gap are
  // refused, never decoded into wrong bytes: the inner decoder conceals the missing picture, the
  // reconstruction's CRC-32C does not.
  auto enc2 = delta_video("none"), dec2 = delta_video("none");
  int refused = 0;
  for (int f = 0; f < 6; ++f) {
    const PassBuffer in = test::make_world_pass(gbuffer(f, 4.0), PassKind::Ao);
    std::vector<uint8_t> coded;
    enc2->encode(in, {}, coded);
    if (f == 2) continue;
    PassBuffer out;
    std::string error;
    if (!dec2->decode(coded, in.desc, out, error)) ++refused;
  }
  EXPECT_EQ(refused, 3) << "frames 3..5 are predicted through the lost frame 2";
}

TEST(PassCoding, LossyDeltaRefusesWhatItCannotCarry) {
  auto c = delta_video("reprojection");
  EXPECT_NE(c->refuses({PassKind::Visibility, kW, kH, 3, 1}).find("bitmask"), std::string::npos);
  EXPECT_NE(c->refuses({PassKind::Colour, kW, kH, 3, 255}).find("colour"), std::string::npos);
  EXPECT_TRUE(c->refuses({PassKind::Ao, kW, kH, 1, 8}).empty());
  try {
    registries().codecs.create("delta_video", {{"inner", "h264"}, {"crf", 60}});
    FAIL() << "crf 60 accepted for h264";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("inner h264"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace dhr
