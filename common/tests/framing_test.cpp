#include "penumbra/common/framing.h"

#include <gtest/gtest.h>

namespace penumbra {
namespace {

TEST(FramingTest, RoundTripsOneFrame) {
  const std::string frame = EncodeFrame("hello");
  ASSERT_EQ(frame.size(), kFrameHeaderBytes + 5);
  EXPECT_EQ(frame[0], 5);  // little-endian length
  FrameDecoder decoder(100);
  decoder.Feed(frame.data(), frame.size());
  auto next = decoder.Next();
  ASSERT_TRUE(next.ok());
  ASSERT_TRUE(next->has_value());
  EXPECT_EQ(**next, "hello");
  auto after = decoder.Next();
  ASSERT_TRUE(after.ok());
  EXPECT_FALSE(after->has_value());
  EXPECT_EQ(decoder.Buffered(), 0u);
}

TEST(FramingTest, ReassemblesFramesSplitAtEveryByte) {
  std::string stream;
  AppendFrame(stream, "first");
  AppendFrame(stream, "");
  AppendFrame(stream, std::string(300, 'x'));
  FrameDecoder decoder(1000);
  std::vector<std::string> frames;
  for (char c : stream) {
    decoder.Feed(&c, 1);
    while (true) {
      auto next = decoder.Next();
      ASSERT_TRUE(next.ok());
      if (!next->has_value()) break;
      frames.emplace_back(**next);
    }
  }
  ASSERT_EQ(frames.size(), 3u);
  EXPECT_EQ(frames[0], "first");
  EXPECT_EQ(frames[1], "");
  EXPECT_EQ(frames[2], std::string(300, 'x'));
}

TEST(FramingTest, RejectsFrameOverLimitBeforeBufferingIt) {
  const std::string frame = EncodeFrame(std::string(101, 'y'));
  FrameDecoder decoder(100);
  decoder.Feed(frame.data(), kFrameHeaderBytes);  // only the header
  auto next = decoder.Next();
  ASSERT_FALSE(next.ok());
  EXPECT_NE(next.error().message.find("101"), std::string::npos);
  EXPECT_NE(next.error().message.find("100"), std::string::npos);
  // The decoder stays failed.
  decoder.Feed(frame.data() + kFrameHeaderBytes, 101);
  EXPECT_FALSE(decoder.Next().ok());
}

TEST(FramingTest, AcceptsFrameExactlyAtLimit) {
  const std::string frame = EncodeFrame(std::string(100, 'z'));
  FrameDecoder decoder(100);
  decoder.Feed(frame.data(), frame.size());
  auto next = decoder.Next();
  ASSERT_TRUE(next.ok());
  ASSERT_TRUE(next->has_value());
  EXPECT_EQ((*next)->size(), 100u);
}

TEST(FramingTest, HugeLengthPrefixIsAnErrorNotAnAllocation) {
  const char header[4] = {'\xff', '\xff', '\xff', '\xff'};
  FrameDecoder decoder;
  decoder.Feed(header, 4);
  EXPECT_FALSE(decoder.Next().ok());
}

TEST(FramingTest, BufferCompactsOnLongStreams) {
  FrameDecoder decoder(64);
  const std::string frame = EncodeFrame(std::string(60, 'a'));
  for (int i = 0; i < 10000; ++i) {
    decoder.Feed(frame.data(), frame.size());
    auto next = decoder.Next();
    ASSERT_TRUE(next.ok() && next->has_value());
  }
  EXPECT_EQ(decoder.Buffered(), 0u);
}

}  // namespace
}  // namespace penumbra
