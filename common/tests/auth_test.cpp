#include "penumbra/common/auth.h"

#include <sys/stat.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>

#include <gtest/gtest.h>

namespace penumbra {
namespace {

class TokenFileTest : public ::testing::Test {
 protected:
  void SetUp() override {
    std::string pattern = (std::filesystem::temp_directory_path() / "penumbra-auth-test-XXXXXX").string();
    ASSERT_NE(::mkdtemp(pattern.data()), nullptr);
    dir_ = pattern;
  }
  void TearDown() override { std::filesystem::remove_all(dir_); }

  std::filesystem::path Write(const std::string& name, const std::string& bytes, mode_t mode = 0600) {
    const auto path = dir_ / name;
    std::ofstream(path, std::ios::binary) << bytes;
    ::chmod(path.c_str(), mode);
    return path;
  }

  std::filesystem::path dir_;
};

TEST_F(TokenFileTest, TrailingNewlinesAreStrippedAndNothingElse) {
  auto token = ReadAuthTokenFile(Write("lf", "s3cret-token\n"));
  ASSERT_TRUE(token.ok()) << token.error().message;
  EXPECT_EQ(token->token, "s3cret-token");
  EXPECT_TRUE(token->warning.empty()) << "mode 600 draws no warning";

  token = ReadAuthTokenFile(Write("crlf", "s3cret-token\r\n"));
  ASSERT_TRUE(token.ok());
  EXPECT_EQ(token->token, "s3cret-token");

  token = ReadAuthTokenFile(Write("none", " a b "));
  ASSERT_TRUE(token.ok());
  EXPECT_EQ(token->token, " a b ") << "inner and leading spaces are part of the token";
}

TEST_F(TokenFileTest, EmptyMissingAndOversizedFilesAreClearErrors) {
  for (const std::string& content : {std::string(), std::string("\n"), std::string("\r\n\n")}) {
    auto token = ReadAuthTokenFile(Write("empty", content));
    ASSERT_FALSE(token.ok());
    EXPECT_NE(token.error().message.find("holds no token"), std::string::npos) << token.error().message;
  }
  auto missing = ReadAuthTokenFile(dir_ / "missing");
  ASSERT_FALSE(missing.ok());
  EXPECT_NE(missing.error().message.find("missing"), std::string::npos) << "names the file: " << missing.error().message;

  auto directory = ReadAuthTokenFile(dir_);
  ASSERT_FALSE(directory.ok());
  EXPECT_NE(directory.error().message.find("not a regular file"), std::string::npos) << directory.error().message;

  const std::string large(kMaxAuthTokenBytes + 1, 'x');
  auto oversized = ReadAuthTokenFile(Write("large", large));
  ASSERT_FALSE(oversized.ok());
  EXPECT_NE(oversized.error().message.find("larger than"), std::string::npos) << oversized.error().message;
  EXPECT_EQ(oversized.error().message.find("xxxx"), std::string::npos) << "the content is never quoted";

  auto atLimit = ReadAuthTokenFile(Write("limit", std::string(kMaxAuthTokenBytes, 'y')));
  ASSERT_TRUE(atLimit.ok()) << atLimit.error().message;
  EXPECT_EQ(atLimit->token.size(), kMaxAuthTokenBytes);
}

TEST_F(TokenFileTest, AFileOthersCanReadDrawsAWarning) {
  auto token = ReadAuthTokenFile(Write("shared", "tok\n", 0644));
  ASSERT_TRUE(token.ok());
  EXPECT_EQ(token->token, "tok");
  EXPECT_NE(token->warning.find("chmod 600"), std::string::npos) << token->warning;
  EXPECT_NE(token->warning.find("644"), std::string::npos) << token->warning;
  EXPECT_EQ(token->warning.find("tok\n"), std::string::npos);

  token = ReadAuthTokenFile(Write("group", "tok\n", 0640));
  ASSERT_TRUE(token.ok());
  EXPECT_FALSE(token->warning.empty()) << "group-readable also warns";
}

TEST(AuthTokenTest, MatchesOnlyTheExactToken) {
  EXPECT_TRUE(AuthTokenMatches("abc", "abc"));
  EXPECT_FALSE(AuthTokenMatches("abd", "abc"));
  EXPECT_FALSE(AuthTokenMatches("ab", "abc"));
  EXPECT_FALSE(AuthTokenMatches("abcd", "abc"));
  EXPECT_FALSE(AuthTokenMatches("", "abc"));
  EXPECT_FALSE(AuthTokenMatches(std::string("abc\0", 4), "abc"));
}

TEST(AuthTokenTest, HelloCheckAcceptsAllWithoutATokenAndOnlyTheTokenWithOne) {
  wire::Hello hello;
  wire::ErrorCode code = wire::ERROR_CODE_UNSPECIFIED;
  EXPECT_TRUE(CheckHelloToken(hello, "", &code).ok()) << "no token configured: as before";
  hello.set_auth_token("anything");
  EXPECT_TRUE(CheckHelloToken(hello, "", &code).ok());

  hello.clear_auth_token();
  auto none = CheckHelloToken(hello, "right-token", &code);
  ASSERT_FALSE(none.ok());
  EXPECT_EQ(code, wire::ERROR_CODE_AUTH_FAILED);
  EXPECT_NE(none.error().message.find("carries none"), std::string::npos) << none.error().message;

  code = wire::ERROR_CODE_UNSPECIFIED;
  hello.set_auth_token("wrong-token");
  auto wrong = CheckHelloToken(hello, "right-token", &code);
  ASSERT_FALSE(wrong.ok());
  EXPECT_EQ(code, wire::ERROR_CODE_AUTH_FAILED);
  EXPECT_EQ(wrong.error().message.find("right-token"), std::string::npos) << "the server's token never in a message";
  EXPECT_EQ(wrong.error().message.find("wrong-token"), std::string::npos) << "nor the peer's";

  hello.set_auth_token("right-token");
  EXPECT_TRUE(CheckHelloToken(hello, "right-token", &code).ok());
}

}  // namespace
}  // namespace penumbra
