#include "core/pass_denoisers.h"

#include <algorithm>

namespace dhr {

PassDenoisers::PassDenoisers(const SimConfig& c, const Registries& r) : registries(r) {
  ao_is_none = c.ao_denoiser.name == "none";
  soft_is_none = c.visibility_denoiser.name == "none";
  if (!ao_is_none) ao = registries.denoisers.create(c.ao_denoiser.name, c.ao_denoiser.params);
  soft_choice = c.visibility_denoiser;
}

void PassDenoisers::run(const GBuffer& gbuf, uint32_t frame, std::optional<PassBuffer>& vis,
                        std::optional<PassBuffer>& ao_buf) {
  if (ao_buf && !ao_is_none) {
    ImageU8 out;
    const ImageU8 noisy = pass_plane(*ao_buf, 0);
    ao->denoise({gbuf, noisy, ao_buf->desc.full_scale, frame, true}, out);
    ao_buf->bytes.assign(out.pixels().begin(), out.pixels().end());
    ao_buf->desc.full_scale = 255;
  }
  if (vis && vis->desc.kind == PassKind::SoftVisibility && !soft_is_none) {
    const int lights = vis->desc.channels;
    while (int(soft.size()) < lights) soft.push_back(registries.denoisers.create(soft_choice.name, soft_choice.params));
    const size_t n = size_t(vis->desc.width) * size_t(vis->desc.height);
    for (int l = 0; l < lights; ++l) {
      ImageU8 out;
      const ImageU8 noisy = pass_plane(*vis, l);
      soft[size_t(l)]->denoise({gbuf, noisy, vis->desc.full_scale, frame, true}, out);
      std::copy(out.pixels().begin(), out.pixels().end(), vis->bytes.begin() + std::ptrdiff_t(size_t(l) * n));
    }
    vis->desc.full_scale = 255;
  }
}

}  // namespace dhr
