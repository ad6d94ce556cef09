#include "penumbra/common/logging.h"

#include <spdlog/formatter.h>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

namespace penumbra {
namespace {

std::string FormatJson(std::string_view logger, spdlog::level::level_enum level, std::string_view text) {
  spdlog::details::log_msg msg(spdlog::string_view_t(logger.data(), logger.size()), level,
                               spdlog::string_view_t(text.data(), text.size()));
  spdlog::memory_buf_t out;
  MakeJsonLogFormatter()->format(msg, out);
  return std::string(out.data(), out.size());
}

TEST(JsonLogTest, EveryLineIsOneJsonObjectWhateverTheMessageHolds) {
  const std::string awkward = std::string("quote \" backslash \\ newline \n tab \t bell \x07 ") +
                              "utf-8 \xc3\xa9\xe2\x82\xac invalid \xff\xc3 end";
  const std::string line = FormatJson("sma.client", spdlog::level::warn, awkward);
  ASSERT_FALSE(line.empty());
  EXPECT_EQ(line.back(), '\n');
  EXPECT_EQ(line.find('\n'), line.size() - 1) << "one line only: " << line;
  const auto json = nlohmann::json::parse(line);  // throws (fails the test) if invalid
  EXPECT_EQ(json["level"], "warning");
  EXPECT_EQ(json["logger"], "sma.client");
  const std::string message = json["message"];
  EXPECT_EQ(message, std::string("quote \" backslash \\ newline \n tab \t bell \x07 ") +
                         "utf-8 \xc3\xa9\xe2\x82\xac invalid \xef\xbf\xbd\xef\xbf\xbd end");
  EXPECT_TRUE(json["thread"].is_number_integer());
  const std::string time = json["time"];
  EXPECT_EQ(time.size(), 24u) << time;  // 2026-11-24T11:20:03.123Z
  EXPECT_EQ(time.back(), 'Z');
}

TEST(JsonLogTest, UnknownFormatIsRefused) {
  EXPECT_FALSE(SetupLogFormat("xml"));
  EXPECT_TRUE(SetupLogFormat("text"));
}

}  // namespace
}  // namespace penumbra
