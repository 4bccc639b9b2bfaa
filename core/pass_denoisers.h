// The server's denoising of one frame's passes, shared by the simulator (core/frame_loop) and
// live mode (core/live): the AO counts through the AO denoiser, and each light's plane of an
// 8-bit soft-visibility pass through its own instance of the visibility denoiser (each keeps
// its own history). The "none" denoiser sends the raw counts (full_scale = N rays), as the
// paper does; any other sends 0..255. Bitmasks are never denoised.
#pragma once

#include "core/backend.h"
#include "core/run_config.h"
#include "core/gbuffer.h"
#include "core/pass_buffer.h"

#include <memory>
#include <optional>
#include <vector>

namespace dhr {

struct PassDenoisers {
  std::unique_ptr<Denoiser> ao;
  std::vector<std::unique_ptr<Denoiser>> soft;  // one per light
  bool ao_is_none = true, soft_is_none = true;
  BackendChoice soft_choice;
  const Registries& registries;

  PassDenoisers(const SimConfig& c, const Registries& registries);
  // Denoises in place (either buffer may be absent).
  void run(const GBuffer& gbuf, uint32_t frame, std::optional<PassBuffer>& vis, std::optional<PassBuffer>& ao_buf);
};

}  // namespace dhr
