// Layout conversions of a Visibility buffer (the paper's per-pixel light bitmask).
//
// Canonical layout (core/buffers/pass_buffer.h): interleaved per pixel, B = ceil(lights/8) bytes per
// pixel, bit l of the pixel (little-endian across its bytes) = light l visible. The bits at
// positions >= lights (the unused top bits of the last byte) must be zero.
//
// Planar layout: one bit-plane per light, plane l stored after plane l-1; each plane holds
// the w*h pixels in row-major order packed 8 to a byte, pixel i in bit (i % 8) of byte i / 8
// (LSB first, the same bit order as the interleaved layout), ceil(w*h/8) bytes, the padding
// bits of its last byte zero. Planes compress better with generic LZ coders because every
// byte then holds 8 neighbouring pixels of one light: each light's shadow edges stay
// together instead of being mixed with the other lights' bits. tests/backends/test_codecs.cpp
// (`Lz4Zstd.PlanesAreSmallerThanInterleavedOnBitmasks`) checks that lz4 and zstd code a 4-light
// bitmask smaller as planes; tests/backends/bench_codecs.cpp sizes and times both layouts
// (`hard_vis4_planes` against `hard_vis4_interleaved`).
//
// The conversions are exact in both directions; they work 8 pixels at a time with one 8x8
// bit-matrix transpose per byte column (Hacker's Delight, 2nd ed., section 7-3).
#pragma once

#include "core/buffers/pass_buffer.h"

#include <cstddef>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

namespace dhr {

// Bytes of one bit-plane of a width x height image: ceil(w*h/8).
size_t visibility_plane_bytes(int width, int height);
// Bytes of the planar layout of a Visibility buffer: lights * visibility_plane_bytes.
size_t visibility_planes_size(const PassDesc& desc);

// Interleaved -> planes. `out` must hold exactly visibility_planes_size(desc) bytes.
// Throws dhr::Error when desc is not a valid Visibility description, a size does not match,
// or a pixel has an unused bit (>= lights) set: such bits cannot survive the conversion, so
// they are bad input rather than something to drop silently.
void visibility_to_planes(const PassDesc& desc, std::span<const uint8_t> interleaved, std::span<uint8_t> out);

// Planes -> interleaved. `out` must hold exactly desc.byte_size() bytes. Throws dhr::Error on
// an invalid desc or wrong sizes; returns false (corrupt input, `out` unspecified) when a
// plane's padding bits are set, which visibility_to_planes never produces.
bool visibility_from_planes(const PassDesc& desc, std::span<const uint8_t> planes, std::span<uint8_t> out);

// True when no pixel of an interleaved Visibility buffer has a bit >= lights set.
bool visibility_unused_bits_clear(const PassDesc& desc, std::span<const uint8_t> interleaved);

// ---- For generic byte codecs (lz4, zstd, delta): the layout a Visibility buffer is coded in.
// Other pass kinds are always coded as their canonical bytes.
enum class VisibilityLayout { Interleaved, Planes };

// Parses "interleaved" or "planes" (a codec's `layout` parameter); throws dhr::Error otherwise.
VisibilityLayout parse_visibility_layout(const std::string& name);
// The number of bytes a generic codec compresses for a buffer of `desc`.
size_t coded_size(const PassDesc& desc, VisibilityLayout layout);
// The bytes to compress for `in`: its own bytes, or (Visibility in planes) its planes written
// into `scratch`. Throws dhr::Error when the buffer does not match its description.
std::span<const uint8_t> to_coded_layout(const PassBuffer& in, VisibilityLayout layout, std::vector<uint8_t>& scratch);
// True when decompressed bytes must go through `scratch` (planes) rather than straight into
// the output buffer.
bool needs_layout_conversion(const PassDesc& desc, VisibilityLayout layout);
// Converts decompressed planes back into the canonical layout. False (with `error` set) when
// the planes are corrupt.
bool from_coded_planes(const PassDesc& desc, std::span<const uint8_t> planes, std::vector<uint8_t>& out,
                       std::string& error);

}  // namespace dhr
