// none: no filtering. Rescales the noisy value from 0..full_scale to 0..255 (rounded), so that
// every denoiser's output has the same meaning (255 = unoccluded / fully visible).
//
// Parameters: none.   Example: {"denoiser": "none"}
#include "core/backend.h"

namespace dhr {
namespace {

class NoneDenoiser final : public Denoiser {
 public:
  void denoise(const DenoiseInput& in, ImageU8& out) override {
    const int scale = in.full_scale < 1 ? 1 : in.full_scale;
    out.resize(in.noisy.width(), in.noisy.height());
    for (size_t i = 0; i < in.noisy.size(); ++i) {
      const int v = in.noisy[i] > scale ? scale : in.noisy[i];
      out[i] = uint8_t((v * 255 + scale / 2) / scale);
    }
  }
  void reset() override {}
};

}  // namespace

DenoiserEntry make_none_denoiser() {
  return {"none", "no denoising: the traced values rescaled to 0..255", {},
          [](const Params&) { return std::make_unique<NoneDenoiser>(); }};
}

}  // namespace dhr
