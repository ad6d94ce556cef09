// Statistics lines: one JSON object per line with every documented field.

#include "penumbra/client/stats_line.h"

#include <fstream>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "support/process.h"

namespace penumbra::client {
namespace {

TEST(StatsLineTest, WritesOneJsonObjectPerLine) {
  const std::string path = testing::MakeTempDir("penumbra-stats-test") + "/stats.jsonl";
  auto writer = StatsLineWriter::Open(path);
  ASSERT_TRUE(writer.ok()) << writer.error().message;
  FrameStats first;
  first.frame = 1;
  first.trianglesHeld = 36;
  first.connection = "connected";
  ASSERT_TRUE(writer->Write(first).ok());
  FrameStats second = first;
  second.frame = 2;
  second.converged = true;
  second.viewToFirstDeltaMs = 12.5;
  second.sma = SmaReport{36, 30, true, 4};
  second.memory = ReadProcessMemory();
  second.sceneEpoch = 4;
  second.movesSent = 3;
  second.movesPending = 1;
  ASSERT_TRUE(writer->Write(second).ok());

  std::ifstream in(path);
  std::string line;
  std::vector<nlohmann::json> lines;
  while (std::getline(in, line)) lines.push_back(nlohmann::json::parse(line));
  ASSERT_EQ(lines.size(), 2u);
  for (const char* field : {"frame", "time_s", "triangles_held", "vertices_held", "bytes_received", "samples_pending",
                            "converged", "view_to_first_delta_ms", "fps", "rss_bytes", "peak_rss_bytes", "connection",
                            "connections", "sma_triangles_held", "sma_vertices_held", "sma_agrees", "scene_epoch",
                            "moves_sent", "moves_pending"})
    EXPECT_TRUE(lines[0].contains(field)) << field;
  EXPECT_TRUE(lines[0]["view_to_first_delta_ms"].is_null());
  EXPECT_TRUE(lines[0]["sma_agrees"].is_null());
  EXPECT_EQ(lines[1]["view_to_first_delta_ms"].get<double>(), 12.5);
  EXPECT_EQ(lines[1]["sma_vertices_held"].get<int>(), 30);
  EXPECT_TRUE(lines[1]["converged"].get<bool>());
  EXPECT_EQ(lines[1]["scene_epoch"].get<int>(), 4);
  EXPECT_EQ(lines[1]["moves_sent"].get<int>(), 3);
  EXPECT_EQ(lines[1]["moves_pending"].get<int>(), 1);
  EXPECT_GT(lines[1]["rss_bytes"].get<uint64_t>(), 0u);
  EXPECT_GE(lines[1]["peak_rss_bytes"].get<uint64_t>(), lines[1]["rss_bytes"].get<uint64_t>());
}

TEST(StatsLineTest, AnUnwritablePathIsAnError) {
  auto writer = StatsLineWriter::Open("/nonexistent-dir/stats.jsonl");
  ASSERT_FALSE(writer.ok());
  EXPECT_NE(writer.error().message.find("/nonexistent-dir/stats.jsonl"), std::string::npos);
}

}  // namespace
}  // namespace penumbra::client
