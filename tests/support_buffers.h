// Realistic synthetic pass buffers for codec tests and benchmarks (and any other test that
// needs plausible server output without tracing rays). Everything is a deterministic function
// of its arguments (random numbers from core/base/rng.h only).
//
// The synthetic scene, in reference pixels of a 1280x720 frame (scaled to the buffer size): a
// wall (top) meeting a floor (bottom) along a horizontal crease, wall panels with vertical
// grooves, floor tiles, and a few spheres and boxes standing in front. AO darkens creases,
// grooves and contact regions, with hard edges at object outlines; lights cast the objects'
// shadows, each light from its own position and with a limited range.
// A camera pan is simulated by shifting the scene by (shift_x_px, shift_y_px) pixels: the
// content moves left/up by that much, and newly exposed parts come in from the right/bottom.
#pragma once

#include "core/buffers/gbuffer.h"
#include "core/buffers/pass_buffer.h"

#include <cstdint>

namespace dhr::test {

struct SyntheticView {
  int width = 64;
  int height = 48;
  double shift_x_px = 0.0;  // camera pan in pixels of this buffer
  double shift_y_px = 0.0;
  uint32_t frame = 0;  // frame index of the noise (Monte Carlo samples differ per frame)
  uint64_t seed = 1;
};

// Every byte `value`; for Visibility, bits >= lights are cleared.
PassBuffer make_constant(const PassDesc& desc, uint8_t value);
// Maximum entropy: independent uniform bytes (Ao/SoftVisibility: uniform in 0..full_scale;
// Visibility: uniform bits for every light, unused bits clear).
PassBuffer make_random(const PassDesc& desc, uint64_t seed);

// The exact (noise-free) ambient visibility of the scene, 0..1 (1 = unoccluded).
double synthetic_ao(double x_ref, double y_ref);

// Raw AO counts: per pixel the number of `rays` (1..255) that escaped, binomial around the
// exact AO (what an N-ray AO pass sends before denoising). full_scale = rays.
PassBuffer make_noisy_ao(const SyntheticView& view, int rays);
// A denoised AO pass: the exact AO rounded to 0..255 (full_scale 255).
PassBuffer make_smooth_ao(const SyntheticView& view);
// Hard shadows of `lights` (1..64) point lights as the paper's per-pixel bitmask.
PassBuffer make_hard_visibility(const SyntheticView& view, int lights);
// Soft shadows: per light the visible fraction with a penumbra. samples = 0: the exact
// fraction, full_scale 255 (denoised); samples = N (1..255): binomial counts of N shadow rays,
// full_scale N.
PassBuffer make_soft_visibility(const SyntheticView& view, int lights, int samples = 0);
// A shaded RGB8 frame of the scene (textured wall and floor, coloured objects, AO, light
// falloff, a little fixed texture noise that moves with the scene).
PassBuffer make_colour(const SyntheticView& view);

// A one-plane pass fixed to the world, for pass-coding tests on real G-buffers: Ao a smooth
// function of each covered pixel's world position, Visibility (one light) a world-space checker
// of 0.5 m squares; background fully lit. A perfect reprojection predicts it everywhere except
// where a surface comes into view.
PassBuffer make_world_pass(const GBuffer& g, PassKind kind);

// PSNR over all bytes with peak 255, in dB; +inf when equal. Sizes must match (else throws).
double buffer_psnr_db(const PassBuffer& a, const PassBuffer& b);

}  // namespace dhr::test
