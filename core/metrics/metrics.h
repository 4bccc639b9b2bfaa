// Image quality metrics, the way the benchmark scores every displayed frame.
//
// SSIM after Wang et al. 2004 ("Image quality assessment: from error visibility to structural
// similarity"): Gaussian window 11x11, sigma 1.5, K1 = 0.01, K2 = 0.03, dynamic range L = 255,
// computed on the 8-bit sRGB-encoded values. Default channel: luma Y' = 0.299 R' + 0.587 G' +
// 0.114 B' (BT.601, as Wang's reference code applies SSIM to colour through rgb2gray);
// SsimChannel::RgbMean averages the SSIM of R, G and B instead. Borders: the window is
// evaluated at every pixel with reflect-101 padding (OpenCV's default, so the value equals
// cv::quality::QualitySSIM on the same plane); the mean over all pixels is reported.
// PSNR: 10 log10(255^2 / MSE) over all three channels; +inf for identical images.
#pragma once

#include "core/buffers/image.h"

namespace dhr {

enum class SsimChannel { Luma, RgbMean };
enum class SsimBorder { Valid, Mirrored };
// The smallest side SsimBorder::Valid accepts (one 11x11 window).
constexpr int kSsimWindow = 11;

struct QualityScores {
  double ssim = 1.0;
  double psnr_db = 0.0;         // +inf when identical
  double mean_abs_error = 0.0;  // mean |a - b| over all channels, in 8-bit levels
};

// PSNR as averaged over frames, in both the simulator and live mode: identical frames (+inf)
// count as 100 dB, so that a mean stays finite and comparable.
constexpr double kPsnrOfIdenticalDb = 100.0;
inline double psnr_for_mean(double psnr_db) { return psnr_db < kPsnrOfIdenticalDb ? psnr_db : kPsnrOfIdenticalDb; }

// Throws dhr::Error when sizes differ, an image is empty, or (Valid) a side is below 11.
QualityScores compare_images(const ImageRGB8& a, const ImageRGB8& b, SsimChannel channel = SsimChannel::Luma,
                             ImageF* ssim_map = nullptr, SsimBorder border = SsimBorder::Mirrored);
// SSIM of two single-channel 8-bit images (same conventions).
double ssim_u8(const ImageU8& a, const ImageU8& b, ImageF* ssim_map = nullptr,
               SsimBorder border = SsimBorder::Mirrored);
double psnr_db(const ImageRGB8& a, const ImageRGB8& b);
ImageU8 luma(const ImageRGB8& image);

// An error map on a fixed colour scale: value 0 -> dark blue ... max_value -> yellow (a
// perceptually ordered ramp), saturating above. With a colour bar strip at the bottom.
ImageRGB8 error_map(const ImageF& error, float max_value, bool with_colour_bar = true);
// Per-pixel absolute luma difference in 8-bit levels.
ImageF abs_luma_difference(const ImageRGB8& a, const ImageRGB8& b);

}  // namespace dhr
