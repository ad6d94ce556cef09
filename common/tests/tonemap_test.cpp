#include "penumbra/common/tonemap.h"

#include <cmath>
#include <vector>

#include <gtest/gtest.h>

namespace penumbra {
namespace {

TEST(ToneMapTest, MeasureLuminanceGivesMaxAndLogAverage) {
  const std::vector<Rgb> values = {Rgb(1.0f), Rgb(4.0f), Rgb(0.0f), Rgb(-1.0f)};
  const ViewLuminance v = MeasureLuminance(values);
  EXPECT_NEAR(v.max, 4.0f, 1e-5f);
  EXPECT_NEAR(v.logAverage, 2.0f, 1e-5f);  // exp((ln 1 + ln 4) / 2); black and negative ignored
  EXPECT_EQ(MeasureLuminance({}).max, 1.0f);
}

TEST(ToneMapTest, DragoMatchesThePapersFormula) {
  // Adaptation luminance 1 and exposure 1: Lw and Lwmax enter unchanged.
  const ViewLuminance view{50.0f, 1.0f};
  const DragoParams p;  // b = 0.85, Ldmax = 100
  for (float lw : {0.01f, 0.5f, 1.0f, 10.0f, 50.0f}) {
    const double expected = (100.0 * 0.01 / std::log10(50.0 + 1.0)) * std::log(lw + 1.0) /
                            std::log(2.0 + 8.0 * std::pow(lw / 50.0, std::log(0.85) / std::log(0.5)));
    EXPECT_NEAR(DragoDisplayLuminance(lw, view, p), std::min(1.0, expected), 1e-5) << lw;
  }
}

TEST(ToneMapTest, DragoIsMonotoneMapsTheMaximumToWhiteAndBlackToBlack) {
  const ViewLuminance view{20.0f, 0.7f};
  const DragoParams p;
  EXPECT_EQ(DragoDisplayLuminance(0.0f, view, p), 0.0f);
  float previous = 0.0f;
  for (float lw = 0.001f; lw <= 20.0f; lw *= 1.5f) {
    const float ld = DragoDisplayLuminance(lw, view, p);
    EXPECT_GE(ld, previous) << lw;
    previous = ld;
  }
  EXPECT_NEAR(DragoDisplayLuminance(20.0f, view, p), 1.0f, 0.02f);
}

TEST(ToneMapTest, ColourKeepsItsHueAndExposureBrightens) {
  const ViewLuminance view{10.0f, 1.0f};
  DragoParams p;
  const Rgb red = ToneMapDrago(Rgb(2.0f, 0.2f, 0.1f), view, p);
  EXPECT_NEAR(red.r / red.g, 10.0f, 1e-3f);
  p.exposure = 4.0f;
  const Rgb brighter = ToneMapDrago(Rgb(2.0f, 0.2f, 0.1f), view, p);
  EXPECT_GT(Luminance(brighter), Luminance(red));
  EXPECT_EQ(ToneMapExposure(Rgb(0.5f, 2.0f, -1.0f), 1.0f), Rgb(0.5f, 1.0f, 0.0f));
}

}  // namespace
}  // namespace penumbra
