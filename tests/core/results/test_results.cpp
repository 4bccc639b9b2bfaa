// Results declared once (core/results/results.h): the image metrics score frames as their functions do,
// aggregates follow the declaration (PSNR of identical frames counts as 100 dB), and the
// frames.csv writer's rows match its header, with empty cells for a pass a run does not have.
#include "core/metrics/flip.h"
#include "core/metrics/metrics.h"
#include "core/results/results.h"

#include <gtest/gtest.h>

#include <cmath>
#include <set>
#include <sstream>

namespace dhr {
namespace {

ImageRGB8 pattern(int w, int h, int seed) {
  ImageRGB8 img(w, h);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const int v = (x * 7 + y * 13 + seed * 31 + (x * y) % 11) & 255;
      img(x, y) = {uint8_t(v), uint8_t(255 - v), uint8_t((v * 3) & 255)};
    }
  return img;
}

size_t index_of(const std::string& name) {
  const auto& m = image_metrics();
  for (size_t i = 0; i < m.size(); ++i)
    if (m[i].name == name) return i;
  ADD_FAILURE() << "no image metric " << name;
  return 0;
}

std::vector<std::string> split(const std::string& line) {
  std::vector<std::string> cells;
  std::stringstream s(line);
  std::string cell;
  while (std::getline(s, cell, ',')) cells.push_back(cell);
  if (!line.empty() && line.back() == ',') cells.push_back("");
  return cells;
}

TEST(Results, ScoreFrameIsTheDeclaredFunctions) {
  const ImageRGB8 a = pattern(48, 32, 1), b = pattern(48, 32, 2);
  const std::vector<double> s = score_frame(a, b);
  ASSERT_EQ(s.size(), image_metrics().size());
  const QualityScores q = compare_images(a, b, SsimChannel::Luma, nullptr, SsimBorder::Valid);
  EXPECT_EQ(s[index_of("ssim")], q.ssim);
  EXPECT_EQ(s[index_of("psnr")], q.psnr_db);
  EXPECT_EQ(s[index_of("flip")], flip(a, b).mean);
  // Step metrics need the previous scored frame: none here.
  EXPECT_TRUE(std::isnan(s[index_of("temporal_error")]));
  // Shown and reference both still: no error of the change, whatever the per-frame error.
  const std::vector<double> still = score_frame(a, b, &a, &b);
  EXPECT_EQ(still[index_of("temporal_error")], 0.0);
  EXPECT_EQ(still[index_of("static_flicker")], 0.0);
  // The reference still, the shown frame changing: flicker.
  const std::vector<double> flicker = score_frame(a, b, &a, &a);
  EXPECT_GT(flicker[index_of("static_flicker")], 1.0);
  EXPECT_EQ(flicker[index_of("static_flicker")], flicker[index_of("temporal_error")]);
  const std::vector<double> same = score_frame(a, a);
  EXPECT_EQ(same[index_of("ssim")], 1.0);
  EXPECT_TRUE(std::isinf(same[index_of("psnr")]));
  EXPECT_THROW(score_frame(a, pattern(47, 32, 1)), std::exception);
}

TEST(Results, MeansFollowTheDeclaration) {
  RunResult r;
  const ImageRGB8 a = pattern(40, 24, 3), b = pattern(40, 24, 4);
  FrameRecord identical, different, unscored;
  identical.scored = different.scored = true;
  identical.local = score_frame(a, a);
  different.local = score_frame(a, b);
  different.scored_ground_truth = true;
  different.ground_truth = score_frame(a, b);
  r.frames = {identical, different, unscored};
  const nlohmann::json m = r.metrics();
  const size_t psnr = index_of("psnr"), ssim = index_of("ssim");
  EXPECT_DOUBLE_EQ(m.at("psnr_local_mean_db").get<double>(), (kPsnrOfIdenticalDb + different.local[psnr]) / 2);
  EXPECT_DOUBLE_EQ(m.at("ssim_local_mean").get<double>(), (1.0 + different.local[ssim]) / 2);
  EXPECT_DOUBLE_EQ(m.at("ssim_ground_truth_mean").get<double>(), different.ground_truth[ssim]);
  EXPECT_TRUE(std::isinf(identical.score("psnr")));
  EXPECT_THROW(unscored.score("ssim"), std::exception);
  EXPECT_THROW(identical.score("no-such-metric"), std::exception);
}

TEST(Results, StatisticsOverFrames) {
  RunResult r;
  // SSIM of five frames 0.9, 0.8, 0.95, 0.7, 0.85 against the local reference (values set directly).
  for (double v : {0.9, 0.8, 0.95, 0.7, 0.85}) {
    FrameRecord f;
    f.scored = true;
    f.local.assign(image_metrics().size(), 30.0);
    f.local[index_of("ssim")] = v;
    r.frames.push_back(f);
  }
  const nlohmann::json m = r.metrics();
  EXPECT_DOUBLE_EQ(m.at("ssim_local_mean").get<double>(), 0.84);
  EXPECT_DOUBLE_EQ(m.at("ssim_local_worst").get<double>(), 0.7);
  EXPECT_DOUBLE_EQ(m.at("ssim_local_worst_5pct").get<double>(), 0.7);  // nearest rank: ceil(0.25) = 1st worst
  // Squared deviations from 0.84 sum to 0.037: sd = sqrt(0.037 / 4); t(4) = 2.776; half-width t sd / sqrt(5).
  EXPECT_NEAR(m.at("ssim_local_ci95").get<double>(), 2.776 * std::sqrt(0.037 / 4) / std::sqrt(5.0), 1e-12);
  EXPECT_EQ(m.at("psnr_local_ci95_db").get<double>(), 0.0);  // every frame 30 dB
  EXPECT_TRUE(m.at("ssim_ground_truth_worst").is_null());    // never scored against the ground truth
  EXPECT_EQ(m.at("frames_scored").get<int>(), 5);
  EXPECT_EQ(m.at("frames_scored_ground_truth").get<int>(), 0);
  EXPECT_DOUBLE_EQ(student_t95(1), 12.706);
  EXPECT_DOUBLE_EQ(student_t95(1000), 1.960);
  EXPECT_THROW(student_t95(0), std::exception);
}

// Stalls: a pass whose newest server frame stays the same for more than stall_after_frames (3)
// display intervals, or that shows none. The AO pass below shows source frames
// 0 1 2 3 3 3 3 3 8 9 - 11 (-: none); the visibility pass updates every frame.
TEST(Results, StallsFrozenFramesAndTheirDurations) {
  RunResult r;
  r.config = {{"display_hz", 60.0}, {"stall_after_frames", 3}};
  const std::vector<int> ao = {0, 1, 2, 3, 3, 3, 3, 3, 8, 9, -1, 11};
  for (size_t k = 0; k < ao.size(); ++k) {
    FrameRecord f;
    f.passes = {{"visibility", int(k)}, {"ao", ao[k]}};
    r.frames.push_back(f);
  }
  const nlohmann::json m = r.metrics();
  // Frame 3 shown for 5 intervals (3..7): frames 4-7 stalled, 7 past the threshold; frame 10 none.
  EXPECT_EQ(m.at("stalls").get<int>(), 2);
  EXPECT_NEAR(m.at("stall_ms_total").get<double>(), 5 * 1000.0 / 60.0, 1e-9);
  EXPECT_NEAR(m.at("stall_ms_longest").get<double>(), 4 * 1000.0 / 60.0, 1e-9);
  EXPECT_EQ(m.at("frames_frozen").get<int>(), 2);
  // Shown for 3 intervals only: no stall at the threshold 3.
  r.frames[6].passes[1].source_frame = 6;
  r.frames[7].passes[1].source_frame = 6;
  r.frames[10].passes[1].source_frame = 10;
  const nlohmann::json n = r.metrics();
  EXPECT_EQ(n.at("stalls").get<int>(), 0);
  EXPECT_EQ(n.at("frames_frozen").get<int>(), 0);
  // A stall that lasts to the run's end counts.
  for (size_t k = 6; k < ao.size(); ++k) r.frames[k].passes[0].source_frame = 5;
  const nlohmann::json e = r.metrics();
  EXPECT_EQ(e.at("stalls").get<int>(), 1);
  EXPECT_NEAR(e.at("stall_ms_total").get<double>(), 6 * 1000.0 / 60.0, 1e-9);
}

TEST(Results, FramesCsvRowsMatchTheHeader) {
  const std::vector<std::string> passes = {"visibility", "ao", "colour"};
  std::string head = frames_csv_header({"run"}, passes);
  ASSERT_EQ(head.back(), '\n');
  head.pop_back();
  const std::vector<std::string> header = split(head);
  FrameRecord f;
  f.frame = 7;
  f.scored = true;
  f.local = score_frame(pattern(16, 16, 1), pattern(16, 16, 5));
  f.passes = {{"visibility", 5, 33.3, 12}, {"ao", -1, 0.0, 0}};
  std::string row = frames_csv_row({"r001"}, f, passes);
  ASSERT_EQ(row.back(), '\n');
  row.pop_back();
  const std::vector<std::string> cells = split(row);
  ASSERT_EQ(cells.size(), header.size()) << row;
  auto cell = [&](const std::string& col) {
    for (size_t i = 0; i < header.size(); ++i)
      if (header[i] == col) return cells[i];
    ADD_FAILURE() << "no column " << col;
    return std::string();
  };
  EXPECT_EQ(cell("run"), "r001");
  EXPECT_EQ(cell("frame"), "7");
  EXPECT_EQ(cell("scored"), "1");
  EXPECT_EQ(cell("ssim_local"), csv_number(f.local[index_of("ssim")]));
  EXPECT_EQ(cell("ssim_ground_truth"), "");  // not scored against the ground truth
  EXPECT_EQ(cell("visibility_source_frame"), "5");
  EXPECT_EQ(cell("visibility_disoccluded"), "12");
  EXPECT_EQ(cell("ao_source_frame"), "-1");    // planned, nothing received yet
  EXPECT_EQ(cell("colour_source_frame"), "");  // not a pass of this run
  EXPECT_EQ(csv_number(std::nan("")), "");
  EXPECT_EQ(csv_number(INFINITY), "inf");
}

TEST(Results, EveryDeclaredNameIsUnique) {
  std::set<std::string> names;
  for (const ImageMetric& m : image_metrics())
    for (Against a : {Against::Local, Against::GroundTruth}) {
      EXPECT_TRUE(names.insert(m.column(a)).second) << m.column(a);
      for (const ImageStatistic& s : image_statistics()) EXPECT_TRUE(names.insert(m.aggregate(a, s.name)).second);
    }
  for (const RunMetric& m : run_metrics()) EXPECT_TRUE(names.insert(m.key).second) << m.key;
  std::set<std::string> pass_keys;
  for (const PassMetric& m : pass_metrics()) EXPECT_TRUE(pass_keys.insert(m.key).second) << m.key;
}

}  // namespace
}  // namespace dhr
