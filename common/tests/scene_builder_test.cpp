#include "penumbra/common/scene.h"

#include <gtest/gtest.h>

namespace penumbra {
namespace {

uint32_t White(SceneBuilder& b) {
  Material m;
  m.name = "white";
  return b.AddMaterial(m);
}

TEST(SceneBuilderTest, FlatQuadSharesVerticesAlongItsDiagonal) {
  SceneBuilder b;
  const uint32_t m = White(b);
  b.AddQuad(Vec3(0), Vec3(1, 0, 0), Vec3(0, 0, -1), m);
  Scene s;
  ASSERT_TRUE(b.BuildInto(s).ok());
  EXPECT_EQ(s.triangles.size(), 2u);
  EXPECT_EQ(s.vertices.size(), 4u);
  for (const Vertex& v : s.vertices) EXPECT_NEAR(v.normal.y, 1.0f, 1e-6f);
}

TEST(SceneBuilderTest, CubeCornersAreSplitIntoOneVertexPerFace) {
  SceneBuilder b;
  const uint32_t m = White(b);
  // Unit cube, outward faces.
  b.AddQuad(Vec3(0, 0, 0), Vec3(1, 0, 0), Vec3(0, 0, 1), m);  // bottom, -y
  b.AddQuad(Vec3(0, 1, 0), Vec3(0, 0, 1), Vec3(1, 0, 0), m);  // top, +y
  b.AddQuad(Vec3(0, 0, 0), Vec3(0, 0, 1), Vec3(0, 1, 0), m);  // -x
  b.AddQuad(Vec3(1, 0, 0), Vec3(0, 1, 0), Vec3(0, 0, 1), m);  // +x
  b.AddQuad(Vec3(0, 0, 0), Vec3(0, 1, 0), Vec3(1, 0, 0), m);  // -z
  b.AddQuad(Vec3(0, 0, 1), Vec3(1, 0, 0), Vec3(0, 1, 0), m);  // +z
  Scene s;
  ASSERT_TRUE(b.BuildInto(s).ok());
  EXPECT_EQ(s.triangles.size(), 12u);
  EXPECT_EQ(s.vertices.size(), 24u);  // 8 corners x 3 faces
  for (uint32_t t = 0; t < s.triangles.size(); ++t) {
    const Vec3 n = s.GeometricNormal(t);
    for (uint32_t v : s.triangles[t].v) EXPECT_NEAR(glm::dot(s.vertices[v].normal, n), 1.0f, 1e-5f);
    // Outward: the normal points away from the cube centre.
    EXPECT_GT(glm::dot(n, s.PointAt(t, 1.0f / 3, 1.0f / 3) - Vec3(0.5f)), 0.0f);
  }
}

TEST(SceneBuilderTest, GentleFoldIsSmoothAndSharpFoldIsSplit) {
  for (float angleDeg : {20.0f, 60.0f}) {
    SceneBuilder b(40.0f);
    const uint32_t m = White(b);
    const float a = angleDeg * kPi / 180.0f;
    // Two triangles sharing the edge (0,0,0)-(0,0,1), folded by `a`.
    b.AddTriangle({Vec3(0, 0, 0), Vec3(0, 0, 1), Vec3(1, 0, 0)}, m);
    b.AddTriangle({Vec3(0, 0, 0), Vec3(-std::cos(a), std::sin(a), 0), Vec3(0, 0, 1)}, m);
    Scene s;
    ASSERT_TRUE(b.BuildInto(s).ok());
    EXPECT_EQ(s.vertices.size(), angleDeg < 40.0f ? 4u : 6u) << angleDeg;
  }
}

TEST(SceneBuilderTest, OppositeSheetsDoNotShareVertices) {
  SceneBuilder b;
  const uint32_t m = White(b);
  b.AddQuad(Vec3(0), Vec3(1, 0, 0), Vec3(0, 0, -1), m);  // facing +y
  b.AddQuad(Vec3(0), Vec3(0, 0, -1), Vec3(1, 0, 0), m);  // same square facing -y
  Scene s;
  ASSERT_TRUE(b.BuildInto(s).ok());
  EXPECT_EQ(s.vertices.size(), 8u);
}

TEST(SceneBuilderTest, ASurfaceListedTwiceIsKeptOnce) {
  SceneBuilder b;
  const uint32_t m = White(b);
  b.AddQuad(Vec3(0), Vec3(1, 0, 0), Vec3(0, 0, -1), m);
  // The same two triangles again, one of them starting at another corner.
  b.AddTriangle({Vec3(0), Vec3(1, 0, 0), Vec3(1, 0, -1)}, m);
  b.AddTriangle({Vec3(1, 0, -1), Vec3(0, 0, -1), Vec3(0)}, m);
  // The reverse orientation is another surface (its back), not a duplicate.
  b.AddTriangle({Vec3(0), Vec3(1, 0, -1), Vec3(1, 0, 0)}, m);
  Scene s;
  ASSERT_TRUE(b.BuildInto(s).ok());
  EXPECT_EQ(b.DuplicateTriangles(), 2u);
  EXPECT_EQ(s.triangles.size(), 3u);
  // The kept pair still shares its diagonal's vertices.
  EXPECT_EQ(s.vertices.size(), 4u + 3u);
}

TEST(SceneBuilderTest, EmptyAndDegenerateMeshesAreErrors) {
  {
    SceneBuilder b;
    White(b);
    Scene s;
    s.name = "empty";
    auto st = b.BuildInto(s);
    ASSERT_FALSE(st.ok());
    EXPECT_NE(st.error().message.find("no triangles"), std::string::npos);
  }
  {
    SceneBuilder b;
    const uint32_t m = White(b);
    b.AddTriangle({Vec3(0), Vec3(1, 0, 0), Vec3(2, 0, 0)}, m);  // collinear
    Scene s;
    EXPECT_FALSE(b.BuildInto(s).ok());
    EXPECT_EQ(b.DegenerateTriangles(), 1u);
  }
}

TEST(SceneBuilderTest, NanCoordinatesAreAnError) {
  SceneBuilder b;
  const uint32_t m = White(b);
  b.AddTriangle({Vec3(0), Vec3(1, 0, 0), Vec3(0, std::nanf(""), 1)}, m);
  Scene s;
  s.sourcePath = "bad.obj";
  auto st = b.BuildInto(s);
  ASSERT_FALSE(st.ok());
  EXPECT_NE(st.error().message.find("bad.obj"), std::string::npos);
  EXPECT_NE(st.error().message.find("non-finite"), std::string::npos);
}

TEST(SceneTest, IdentityChangesWithContentAndEmittersAreFound) {
  auto make = [](float albedo, Rgb emission) {
    SceneBuilder b;
    Material white;
    white.albedo = Rgb(albedo);
    const uint32_t m = b.AddMaterial(white);
    Material light;
    light.emission = emission;
    const uint32_t l = b.AddMaterial(light);
    b.AddQuad(Vec3(0), Vec3(1, 0, 0), Vec3(0, 0, -1), m);
    b.AddQuad(Vec3(0, 1, 0), Vec3(0, 0, -1), Vec3(1, 0, 0), l);
    Scene s;
    EXPECT_TRUE(b.BuildInto(s).ok());
    return s;
  };
  const Scene a = make(0.5f, Rgb(1.0f));
  const Scene a2 = make(0.5f, Rgb(1.0f));
  const Scene b = make(0.6f, Rgb(1.0f));
  EXPECT_EQ(a.identity, a2.identity);
  EXPECT_NE(a.identity, b.identity);
  EXPECT_EQ(a.emissiveTriangles.size(), 2u);
  EXPECT_FLOAT_EQ(a.bounds.max.y, 1.0f);
}

TEST(TextureTest, BilinearLookupFollowsObjVConvention) {
  Texture t;
  t.width = 2;
  t.height = 2;
  // Row 0 (top of image): red, green. Row 1 (bottom): blue, white.
  t.texels = {Rgb(1, 0, 0), Rgb(0, 1, 0), Rgb(0, 0, 1), Rgb(1, 1, 1)};
  const Rgb bottomLeft = t.Sample(Vec2(0.25f, 0.25f));
  EXPECT_NEAR(bottomLeft.b, 1.0f, 1e-5f);
  const Rgb topRight = t.Sample(Vec2(0.75f, 0.75f));
  EXPECT_NEAR(topRight.g, 1.0f, 1e-5f);
  // Repeat wrapping: u + 3 is the same texel.
  const Rgb wrapped = t.Sample(Vec2(3.75f, -0.25f));
  EXPECT_NEAR(wrapped.g, 1.0f, 1e-5f);
  // Centre blends all four equally.
  const Rgb centre = t.Sample(Vec2(0.5f, 0.5f));
  EXPECT_NEAR(centre.r, 0.5f, 1e-5f);
}

}  // namespace
}  // namespace penumbra
