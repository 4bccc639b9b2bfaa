// none: no filtering. The values pass through unchanged with their own scale (raw counts of
// N rays stay 0..N, full scale N), as the paper sends them; clamped to the scale.
//
// Parameters: none.   Example: {"name": "none"}
#include "core/backend/backend.h"

namespace dhr {
namespace {

class NoneDenoiser final : public Denoiser {
 public:
  void denoise(const DenoiseInput& in, ImageU8& out) override {
    const int scale = output_full_scale(in.full_scale);
    out.resize(in.noisy.width(), in.noisy.height());
    for (size_t i = 0; i < in.noisy.size(); ++i) out[i] = in.noisy[i] > scale ? uint8_t(scale) : in.noisy[i];
  }
  void reset() override {}
  int output_full_scale(int input_full_scale) const override {
    return input_full_scale < 1 ? 1 : input_full_scale > 255 ? 255 : input_full_scale;
  }
  bool keeps_history() const override { return false; }
};

}  // namespace

DenoiserEntry make_none_denoiser() {
  return {
      "none", "no denoising: the traced values as they are, with their own scale (raw counts)", {}, [](const Params&) {
        return std::make_unique<NoneDenoiser>();
      }};
}

}  // namespace dhr
