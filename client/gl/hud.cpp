#include "gl/hud.h"

#include <algorithm>
#include <cstdint>

#include "gl/bitmap_font.h"

namespace penumbra::client::gl {

namespace {

constexpr int kFirstGlyph = 32;
constexpr int kGlyphCount = 95;
constexpr int kAdvance = kGlyphWidth + 1;   // font pixels between letters
constexpr int kLineHeight = kCellHeight + 1;
constexpr int kMargin = 4;                  // font pixels around the text

constexpr const char* kHudVertexShader = R"(#version 330 core
layout(location = 0) in vec2 aPixel;   // from the viewport's top-left
layout(location = 1) in vec2 aTexel;   // in the font texture; x < 0 marks the panel
uniform vec2 uViewport;
out vec2 vTexel;
void main() {
  vTexel = aTexel;
  gl_Position = vec4(2.0 * aPixel.x / uViewport.x - 1.0, 1.0 - 2.0 * aPixel.y / uViewport.y, 0.0, 1.0);
}
)";

constexpr const char* kHudFragmentShader = R"(#version 330 core
in vec2 vTexel;
uniform sampler2D uFont;
layout(location = 0) out vec4 outColour;
void main() {
  if (vTexel.x < 0.0) {
    outColour = vec4(0.0, 0.0, 0.0, 0.6);
    return;
  }
  if (texelFetch(uFont, ivec2(vTexel), 0).r < 0.5) discard;
  outColour = vec4(0.95, 0.95, 0.85, 1.0);
}
)";

void AddQuad(std::vector<float>& v, float x0, float y0, float x1, float y1, float u0, float t0, float u1, float t1) {
  const float quad[6][4] = {{x0, y0, u0, t0}, {x1, y0, u1, t0}, {x1, y1, u1, t1},
                            {x0, y0, u0, t0}, {x1, y1, u1, t1}, {x0, y1, u0, t1}};
  for (const auto& corner : quad) v.insert(v.end(), corner, corner + 4);
}

}  // namespace

Expected<Hud> Hud::Create() {
  auto program = BuildProgram("hud", kHudVertexShader, kHudFragmentShader);
  if (!program) return program.error();
  std::vector<uint8_t> texels(size_t(kGlyphCount * kGlyphWidth * kCellHeight), 0);
  for (int g = 0; g < kGlyphCount; ++g) {
    const auto rows = GlyphRows(char(kFirstGlyph + g));
    for (int y = 0; y < kCellHeight; ++y)
      for (int x = 0; x < kGlyphWidth; ++x)
        if (rows[size_t(y)] & (1u << (kGlyphWidth - 1 - x)))
          texels[size_t(y * kGlyphCount * kGlyphWidth + g * kGlyphWidth + x)] = 255;
  }
  Texture font = MakeTexture();
  glBindTexture(GL_TEXTURE_2D, font.id());
  glPixelStorei(GL_UNPACK_ALIGNMENT, 1);
  // Row y of the texture is font row y (top first); the shader fetches by texel.
  glTexImage2D(GL_TEXTURE_2D, 0, GL_R8, kGlyphCount * kGlyphWidth, kCellHeight, 0, GL_RED, GL_UNSIGNED_BYTE,
               texels.data());
  glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_NEAREST);
  glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_NEAREST);
  VertexArray vao = MakeVertexArray();
  Buffer buffer = MakeBuffer();
  glBindVertexArray(vao.id());
  glBindBuffer(GL_ARRAY_BUFFER, buffer.id());
  glEnableVertexAttribArray(0);
  glVertexAttribPointer(0, 2, GL_FLOAT, GL_FALSE, 4 * sizeof(float), nullptr);
  glEnableVertexAttribArray(1);
  glVertexAttribPointer(1, 2, GL_FLOAT, GL_FALSE, 4 * sizeof(float), reinterpret_cast<void*>(2 * sizeof(float)));
  glBindVertexArray(0);
  if (auto error = TakeGlError("creating the HUD"); !error.empty()) return Fail(error);
  return Hud(std::move(*program), std::move(font), std::move(vao), std::move(buffer));
}

void Hud::Draw(const std::vector<std::string>& lines, glm::ivec2 viewport, int scale) {
  if (lines.empty()) return;
  const float s = float(std::max(scale, 1));
  size_t longest = 0;
  for (const auto& line : lines) longest = std::max(longest, line.size());
  vertices_.clear();
  AddQuad(vertices_, 0.0f, 0.0f, s * float(2 * kMargin + int(longest) * kAdvance),
          s * float(2 * kMargin + int(lines.size()) * kLineHeight), -1.0f, -1.0f, -1.0f, -1.0f);
  for (size_t row = 0; row < lines.size(); ++row) {
    const float y = s * float(kMargin + int(row) * kLineHeight);
    for (size_t col = 0; col < lines[row].size(); ++col) {
      const char c = lines[row][col];
      if (c == ' ') continue;
      const int glyph = (c < kFirstGlyph || c >= kFirstGlyph + kGlyphCount) ? '?' - kFirstGlyph : c - kFirstGlyph;
      const float x = s * float(kMargin + int(col) * kAdvance);
      const float u = float(glyph * kGlyphWidth);
      AddQuad(vertices_, x, y, x + s * kGlyphWidth, y + s * kCellHeight, u, 0.0f, u + kGlyphWidth, kCellHeight);
    }
  }
  glUseProgram(program_.id());
  glUniform2f(glGetUniformLocation(program_.id(), "uViewport"), float(viewport.x), float(viewport.y));
  glUniform1i(glGetUniformLocation(program_.id(), "uFont"), 0);
  glActiveTexture(GL_TEXTURE0);
  glBindTexture(GL_TEXTURE_2D, font_.id());
  glBindVertexArray(vao_.id());
  glBindBuffer(GL_ARRAY_BUFFER, buffer_.id());
  glBufferData(GL_ARRAY_BUFFER, GLsizeiptr(vertices_.size() * sizeof(float)), vertices_.data(), GL_STREAM_DRAW);
  glEnable(GL_BLEND);
  glBlendFunc(GL_SRC_ALPHA, GL_ONE_MINUS_SRC_ALPHA);
  glDisable(GL_DEPTH_TEST);
  glDrawArrays(GL_TRIANGLES, 0, GLsizei(vertices_.size() / 4));
  glDisable(GL_BLEND);
  glBindVertexArray(0);
}

}  // namespace penumbra::client::gl
