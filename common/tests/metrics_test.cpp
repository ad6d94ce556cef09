#include "penumbra/common/metrics.h"

#include <cmath>
#include <thread>

#include <gtest/gtest.h>

namespace penumbra::metrics {
namespace {

TEST(HistogramTest, CountsEachObservationInItsBucketCumulatively) {
  Histogram h({0.1, 1.0, 10.0});
  for (double v : {0.05, 0.1, 0.5, 5.0, 50.0, 500.0}) h.Observe(v);
  const Histogram::Snapshot s = h.Read();
  ASSERT_EQ(s.cumulative.size(), 4u);
  EXPECT_EQ(s.cumulative[0], 2u);  // le 0.1 (bounds are inclusive)
  EXPECT_EQ(s.cumulative[1], 3u);  // le 1
  EXPECT_EQ(s.cumulative[2], 4u);  // le 10
  EXPECT_EQ(s.cumulative[3], 6u);  // +Inf
  EXPECT_EQ(s.count, 6u);
  EXPECT_DOUBLE_EQ(s.sum, 0.05 + 0.1 + 0.5 + 5.0 + 50.0 + 500.0);
}

TEST(HistogramTest, ObservationsFromManyThreadsAreAllCounted) {
  Histogram h(LatencyBucketsSeconds());
  std::vector<std::thread> threads;
  for (int t = 0; t < 4; ++t)
    threads.emplace_back([&h] {
      for (int i = 0; i < 10000; ++i) h.Observe(0.001 * (i % 100));
    });
  for (auto& t : threads) t.join();
  EXPECT_EQ(h.Read().count, 40000u);
  EXPECT_NEAR(h.Read().sum, 4 * 100 * 0.001 * (99 * 100 / 2), 1e-6);
}

TEST(ExpositionTest, WrittenTextParsesBackWithTypesHelpAndEscapedLabels) {
  ExpositionWriter out;
  out.Family("penumbra_test_requests_total", "counter", "Requests\nwith a back\\slash");
  out.Sample("penumbra_test_requests_total", 42, {{"path", "/a\"b\\c\nd"}});
  out.Sample("penumbra_test_requests_total", 7, {{"path", "/other"}});
  out.Family("penumbra_test_memory_bytes", "gauge", "Memory");
  out.Sample("penumbra_test_memory_bytes", 1.5e9);
  out.Family("penumbra_test_odd", "gauge", "Odd values");
  out.Sample("penumbra_test_odd", INFINITY, {{"k", "inf"}});
  out.Sample("penumbra_test_odd", NAN, {{"k", "nan"}});
  Histogram h({1.0, 2.0});
  h.Observe(1.5);
  out.WriteHistogram("penumbra_test_latency_seconds", "Latency", h.Read(), {{"tier", "x"}});

  auto parsed = ParseExposition(out.Text());
  ASSERT_TRUE(parsed) << parsed.error().message << "\n" << out.Text();
  ASSERT_NE(parsed->FindFamily("penumbra_test_requests_total"), nullptr);
  EXPECT_EQ(parsed->FindFamily("penumbra_test_requests_total")->type, "counter");
  EXPECT_EQ(parsed->FindFamily("penumbra_test_requests_total")->help, "Requests\nwith a back\\slash");
  const ParsedSample* odd = parsed->Find("penumbra_test_requests_total", {{"path", "/a\"b\\c\nd"}});
  ASSERT_NE(odd, nullptr);
  EXPECT_EQ(odd->value, 42);
  EXPECT_EQ(parsed->Find("penumbra_test_memory_bytes")->value, 1.5e9);
  EXPECT_TRUE(std::isinf(parsed->Find("penumbra_test_odd", {{"k", "inf"}})->value));
  EXPECT_TRUE(std::isnan(parsed->Find("penumbra_test_odd", {{"k", "nan"}})->value));
  EXPECT_EQ(parsed->Find("penumbra_test_latency_seconds_bucket", {{"le", "1"}})->value, 0);
  EXPECT_EQ(parsed->Find("penumbra_test_latency_seconds_bucket", {{"le", "2"}})->value, 1);
  EXPECT_EQ(parsed->Find("penumbra_test_latency_seconds_bucket", {{"le", "+Inf"}, {"tier", "x"}})->value, 1);
  EXPECT_EQ(parsed->Find("penumbra_test_latency_seconds_count")->value, 1);
  const ParsedSample* sum = parsed->Find("penumbra_test_latency_seconds_sum");
  ASSERT_NE(sum, nullptr);
  EXPECT_EQ(parsed->FamilyOf(*sum)->type, "histogram");
}

TEST(ExpositionTest, ParserRejectsMalformedLinesNamingTheLine) {
  const char* bad[] = {
      "1abc 3\n",                            // name starts with a digit
      "abc{x=\"1\" 3\n",                      // unterminated label set
      "abc{x=1} 3\n",                         // unquoted label value
      "abc{x=\"1\",x=\"2\"} 3\n",             // duplicate label
      "abc three\n",                          // not a number
      "abc 3 notatime\n",                     // bad timestamp
      "abc\n",                                // no value
      "# TYPE abc countr\n",                  // unknown type
      "abc 1\n# TYPE abc gauge\n",            // TYPE after samples
      "# TYPE abc gauge\n# TYPE abc gauge\n", // TYPE twice
      "a 1\nb 1\na 2\n",                      // a family split in two groups
      "abc{x=\"\\q\"} 1\n",                   // invalid escape
  };
  for (const char* text : bad) {
    auto parsed = ParseExposition(text);
    EXPECT_FALSE(parsed) << text;
    if (!parsed) {
      EXPECT_NE(parsed.error().message.find("line "), std::string::npos) << parsed.error().message;
    }
  }
  EXPECT_TRUE(ParseExposition("# a free comment\n\nabc 1 1700000000000\nx:y_z{a=\"\"} -2.5e-3\n"));
}

TEST(WriteCountersTest, GroupsEachFamilyAndCapturesWildcardLabels) {
  const std::vector<CounterSpec> specs = {
      {"renderer.*.connected", "t_renderer_connected", "gauge", "up", "renderer"},
      {"renderer.*.samples_shaded", "t_renderer_samples_shaded_total", "counter", "shaded", "renderer"},
      {"queued_visible", "t_queued", "gauge", "queued", "priority", "visible"},
      {"queued_background", "t_queued", "gauge", "queued", "priority", "background"},
  };
  // Interleaved per renderer, as a StatsReply lists them.
  const std::vector<std::pair<std::string, double>> counters = {
      {"renderer.10.0.0.1:7100.connected", 1},     {"renderer.10.0.0.1:7100.samples_shaded", 5},
      {"renderer.[::1]:7100.connected", 0},        {"renderer.[::1]:7100.samples_shaded", 6},
      {"queued_visible", 3},                       {"queued_background", 4},
      {"something-new", 9},
  };
  ExpositionWriter out;
  WriteCounters(out, "t", counters, specs);
  auto parsed = ParseExposition(out.Text());
  ASSERT_TRUE(parsed) << parsed.error().message << "\n" << out.Text();
  EXPECT_EQ(parsed->Find("t_renderer_connected", {{"renderer", "10.0.0.1:7100"}})->value, 1);
  EXPECT_EQ(parsed->Find("t_renderer_connected", {{"renderer", "[::1]:7100"}})->value, 0);
  EXPECT_EQ(parsed->Find("t_renderer_samples_shaded_total", {{"renderer", "[::1]:7100"}})->value, 6);
  EXPECT_EQ(parsed->FindFamily("t_renderer_samples_shaded_total")->type, "counter");
  EXPECT_EQ(parsed->Find("t_queued", {{"priority", "background"}})->value, 4);
  // A counter without a spec is kept, as a gauge with a valid name.
  ASSERT_NE(parsed->Find("t_something_new"), nullptr);
  EXPECT_EQ(parsed->FindFamily("t_something_new")->type, "gauge");
}

TEST(ResidentMemoryTest, IsPlausibleForThisProcess) {
  auto rss = ResidentMemoryBytes();
  ASSERT_TRUE(rss.has_value());
  EXPECT_GT(*rss, 1u << 20);
  EXPECT_LT(*rss, uint64_t(64) << 30);
}

}  // namespace
}  // namespace penumbra::metrics
