#include "penumbra/common/messages.h"

#include <gtest/gtest.h>

#include "penumbra/common/endpoint.h"
#include "penumbra/common/framing.h"
#include "penumbra/common/logging.h"

namespace penumbra {
namespace {

TEST(MessagesTest, EnvelopeRoundTripsThroughAFrame) {
  wire::Envelope in;
  in.mutable_shade_request()->set_batch_id(42);
  in.mutable_shade_request()->add_sample_ids(7);
  const std::string frame = EncodeEnvelopeFrame(in);
  FrameDecoder decoder;
  decoder.Feed(frame.data(), frame.size());
  auto payload = decoder.Next();
  ASSERT_TRUE(payload.ok() && payload->has_value());
  auto out = DecodeEnvelope(**payload);
  ASSERT_TRUE(out.ok()) << out.error().message;
  ASSERT_TRUE(out->has_shade_request());
  EXPECT_EQ(out->shade_request().batch_id(), 42u);
  EXPECT_EQ(BodyName(*out), "shade_request");
}

TEST(MessagesTest, GarbageAndEmptyPayloadsAreErrors) {
  EXPECT_FALSE(DecodeEnvelope("").ok());  // no body
  EXPECT_FALSE(DecodeEnvelope("\xff\xff\xff\xff\xff").ok());
  const std::string junk = "this is not protobuf at all \x01\x02\x03";
  EXPECT_FALSE(DecodeEnvelope(junk).ok());
}

TEST(MessagesTest, HelloValidation) {
  wire::Hello hello;
  hello.set_protocol_version(kProtocolVersion);
  hello.set_role(wire::ROLE_SMA);
  hello.set_scene_hash(1234);
  wire::ErrorCode code = wire::ERROR_CODE_UNSPECIFIED;
  EXPECT_TRUE(ValidateHello(hello, wire::ROLE_SMA, 1234, &code).ok());
  EXPECT_TRUE(ValidateHello(hello, wire::ROLE_SMA, 0, &code).ok());

  auto bad = ValidateHello(hello, wire::ROLE_SMA, 999, &code);
  ASSERT_FALSE(bad.ok());
  EXPECT_EQ(code, wire::ERROR_CODE_SCENE_MISMATCH);

  hello.set_protocol_version(kProtocolVersion + 1);
  ASSERT_FALSE(ValidateHello(hello, wire::ROLE_SMA, 1234, &code).ok());
  EXPECT_EQ(code, wire::ERROR_CODE_VERSION_MISMATCH);

  hello.set_protocol_version(kProtocolVersion);
  ASSERT_FALSE(ValidateHello(hello, wire::ROLE_CLIENT, 1234, &code).ok());
  EXPECT_EQ(code, wire::ERROR_CODE_UNEXPECTED_MESSAGE);
}

TEST(EndpointTest, ParsesHostPortForms) {
  auto a = ParseHostPort("127.0.0.1:7000");
  ASSERT_TRUE(a.ok());
  EXPECT_EQ(a->host, "127.0.0.1");
  EXPECT_EQ(a->port, 7000);
  auto b = ParseHostPort("[::1]:80");
  ASSERT_TRUE(b.ok());
  EXPECT_EQ(b->host, "::1");
  EXPECT_EQ(b->ToString(), "[::1]:80");
  auto c = ParseHostPort(":9000");
  ASSERT_TRUE(c.ok());
  EXPECT_EQ(c->host, "0.0.0.0");
  auto d = ParseHostPort("renderer:0", /*allowPortZero=*/true);
  ASSERT_TRUE(d.ok());
  EXPECT_EQ(d->port, 0);
}

TEST(EndpointTest, RejectsMalformed) {
  EXPECT_FALSE(ParseHostPort("localhost").ok());
  EXPECT_FALSE(ParseHostPort("localhost:").ok());
  EXPECT_FALSE(ParseHostPort("localhost:70000").ok());
  EXPECT_FALSE(ParseHostPort("localhost:12ab").ok());
  EXPECT_FALSE(ParseHostPort("localhost:0").ok());
  // The message names the range the flag allows (a --listen port may be 0).
  EXPECT_NE(ParseHostPort("localhost:70000").error().message.find("from 1 to 65535"), std::string::npos);
  EXPECT_NE(ParseHostPort("localhost:70000", /*allowPortZero=*/true).error().message.find("from 0 to 65535"),
            std::string::npos);
  EXPECT_FALSE(ParseHostPort("::1:80").ok());
}

// A peer's name is logged: control characters (a forged "[critical]" line)
// are escaped and a long name cut; an over-long Hello is refused.
TEST(PrintableTest, EscapesControlBytesAndCutsLongText) {
  EXPECT_EQ(Printable("renderer-1"), "renderer-1");
  EXPECT_EQ(Printable("evil\n[critical] x"), "evil\\x0a[critical] x");
  EXPECT_EQ(Printable(std::string(100, 'a'), 8), "aaaaaaaa... (100 bytes)");
  wire::Hello hello;
  hello.set_protocol_version(kProtocolVersion);
  hello.set_role(wire::ROLE_CLIENT);
  hello.set_peer_name(std::string(kMaxPeerNameBytes + 1, 'n'));
  wire::ErrorCode code = wire::ERROR_CODE_UNSPECIFIED;
  EXPECT_FALSE(ValidateHello(hello, wire::ROLE_CLIENT, 0, &code).ok());
  EXPECT_EQ(code, wire::ERROR_CODE_INVALID_REQUEST);
  hello.set_peer_name("fine");
  EXPECT_TRUE(ValidateHello(hello, wire::ROLE_CLIENT, 0, &code).ok());
}

}  // namespace
}  // namespace penumbra
