// ChooseAnisotropy: a GPU gets 16x, a software rasteriser isotropic
// filtering, an explicit request wins, and the implementation's limit holds.

#include "penumbra/client/texture_filtering.h"

#include <gtest/gtest.h>

namespace penumbra::client {
namespace {

TEST(TextureFilteringTest, SoftwareRasterizersAreRecognisedByTheirRendererString) {
  EXPECT_TRUE(IsSoftwareRasterizer("llvmpipe (LLVM 15.0.6, 256 bits)"));
  EXPECT_TRUE(IsSoftwareRasterizer("softpipe"));
  EXPECT_TRUE(IsSoftwareRasterizer("Google SwiftShader"));
  EXPECT_TRUE(IsSoftwareRasterizer("Mesa X11 swrast"));
  EXPECT_FALSE(IsSoftwareRasterizer("AMD Radeon RX 6600 (navi23, LLVM 15.0.6, DRM 3.49, 6.1.0-13-amd64)"));
  EXPECT_FALSE(IsSoftwareRasterizer("NVIDIA GeForce RTX 3070/PCIe/SSE2"));
}

TEST(TextureFilteringTest, TheDefaultIsSixteenOnAGpuAndIsotropicOnAsoftwareRasterizer) {
  EXPECT_EQ(ChooseAnisotropy(std::nullopt, "Mesa Intel(R) UHD Graphics 620 (KBL GT2)", 16.0f), 16.0f);
  EXPECT_EQ(ChooseAnisotropy(std::nullopt, "llvmpipe (LLVM 15.0.6, 256 bits)", 16.0f), 1.0f);
}

TEST(TextureFilteringTest, ARequestWinsWithinTheImplementationsLimit) {
  EXPECT_EQ(ChooseAnisotropy(8.0f, "llvmpipe (LLVM 15.0.6, 256 bits)", 16.0f), 8.0f);
  EXPECT_EQ(ChooseAnisotropy(16.0f, "some GPU", 4.0f), 4.0f);
  EXPECT_EQ(ChooseAnisotropy(std::nullopt, "some GPU", 1.0f), 1.0f) << "no anisotropic filtering extension";
  EXPECT_EQ(ChooseAnisotropy(0.5f, "some GPU", 16.0f), 1.0f);
}

}  // namespace
}  // namespace penumbra::client
