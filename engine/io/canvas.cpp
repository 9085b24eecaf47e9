#include "engine/io/canvas.hpp"

#include <algorithm>
#include <cmath>
#include <iterator>

namespace slam::io {
namespace {

// A 5x7 bitmap font: 7 rows per glyph, the 5 low bits of each row from left (bit 4) to right.
struct Glyph {
  char c;
  uint8_t rows[7];
};

constexpr Glyph kFont[] = {
    {'A', {0x0E, 0x11, 0x11, 0x1F, 0x11, 0x11, 0x11}},
    {'B', {0x1E, 0x11, 0x11, 0x1E, 0x11, 0x11, 0x1E}},
    {'C', {0x0E, 0x11, 0x10, 0x10, 0x10, 0x11, 0x0E}},
    {'D', {0x1C, 0x12, 0x11, 0x11, 0x11, 0x12, 0x1C}},
    {'E', {0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x1F}},
    {'F', {0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x10}},
    {'G', {0x0E, 0x11, 0x10, 0x17, 0x11, 0x11, 0x0F}},
    {'H', {0x11, 0x11, 0x11, 0x1F, 0x11, 0x11, 0x11}},
    {'I', {0x0E, 0x04, 0x04, 0x04, 0x04, 0x04, 0x0E}},
    {'J', {0x07, 0x02, 0x02, 0x02, 0x02, 0x12, 0x0C}},
    {'K', {0x11, 0x12, 0x14, 0x18, 0x14, 0x12, 0x11}},
    {'L', {0x10, 0x10, 0x10, 0x10, 0x10, 0x10, 0x1F}},
    {'M', {0x11, 0x1B, 0x15, 0x15, 0x11, 0x11, 0x11}},
    {'N', {0x11, 0x11, 0x19, 0x15, 0x13, 0x11, 0x11}},
    {'O', {0x0E, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E}},
    {'P', {0x1E, 0x11, 0x11, 0x1E, 0x10, 0x10, 0x10}},
    {'Q', {0x0E, 0x11, 0x11, 0x11, 0x15, 0x12, 0x0D}},
    {'R', {0x1E, 0x11, 0x11, 0x1E, 0x14, 0x12, 0x11}},
    {'S', {0x0F, 0x10, 0x10, 0x0E, 0x01, 0x01, 0x1E}},
    {'T', {0x1F, 0x04, 0x04, 0x04, 0x04, 0x04, 0x04}},
    {'U', {0x11, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E}},
    {'V', {0x11, 0x11, 0x11, 0x11, 0x11, 0x0A, 0x04}},
    {'W', {0x11, 0x11, 0x11, 0x15, 0x15, 0x15, 0x0A}},
    {'X', {0x11, 0x11, 0x0A, 0x04, 0x0A, 0x11, 0x11}},
    {'Y', {0x11, 0x11, 0x11, 0x0A, 0x04, 0x04, 0x04}},
    {'Z', {0x1F, 0x01, 0x02, 0x04, 0x08, 0x10, 0x1F}},
    {'0', {0x0E, 0x11, 0x13, 0x15, 0x19, 0x11, 0x0E}},
    {'1', {0x04, 0x0C, 0x04, 0x04, 0x04, 0x04, 0x0E}},
    {'2', {0x0E, 0x11, 0x01, 0x02, 0x04, 0x08, 0x1F}},
    {'3', {0x1F, 0x02, 0x04, 0x02, 0x01, 0x11, 0x0E}},
    {'4', {0x02, 0x06, 0x0A, 0x12, 0x1F, 0x02, 0x02}},
    {'5', {0x1F, 0x10, 0x1E, 0x01, 0x01, 0x11, 0x0E}},
    {'6', {0x06, 0x08, 0x10, 0x1E, 0x11, 0x11, 0x0E}},
    {'7', {0x1F, 0x01, 0x02, 0x04, 0x08, 0x08, 0x08}},
    {'8', {0x0E, 0x11, 0x11, 0x0E, 0x11, 0x11, 0x0E}},
    {'9', {0x0E, 0x11, 0x11, 0x0F, 0x01, 0x02, 0x0C}},
    {' ', {0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00}},
    {'-', {0x00, 0x00, 0x00, 0x1F, 0x00, 0x00, 0x00}},
    {'.', {0x00, 0x00, 0x00, 0x00, 0x00, 0x0C, 0x0C}},
    {',', {0x00, 0x00, 0x00, 0x00, 0x0C, 0x04, 0x08}},
    {':', {0x00, 0x0C, 0x0C, 0x00, 0x0C, 0x0C, 0x00}},
    {'(', {0x02, 0x04, 0x08, 0x08, 0x08, 0x04, 0x02}},
    {')', {0x08, 0x04, 0x02, 0x02, 0x02, 0x04, 0x08}},
    {'/', {0x00, 0x01, 0x02, 0x04, 0x08, 0x10, 0x00}},
    {'_', {0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x1F}},
    {'+', {0x00, 0x04, 0x04, 0x1F, 0x04, 0x04, 0x00}},
    {'%', {0x18, 0x19, 0x02, 0x04, 0x08, 0x13, 0x03}},
    {'=', {0x00, 0x00, 0x1F, 0x00, 0x1F, 0x00, 0x00}},
    {'?', {0x0E, 0x11, 0x01, 0x02, 0x04, 0x00, 0x04}},
};

constexpr const Glyph& kUnknownGlyph = kFont[std::size(kFont) - 1];  // '?'

const Glyph* FindGlyph(char c) {
  if (c >= 'a' && c <= 'z') c = static_cast<char>(c - 'a' + 'A');
  for (const Glyph& g : kFont) {
    if (g.c == c) return &g;
  }
  return nullptr;
}

const Glyph& GlyphFor(char c) {
  const Glyph* g = FindGlyph(c);
  return g != nullptr ? *g : kUnknownGlyph;
}

/// Calls f(u, v) for every set font pixel of `text`: u along the text, v down the glyph rows.
template <typename F>
void ForEachFontPixel(const std::string& text, F&& f) {
  for (size_t k = 0; k < text.size(); ++k) {
    const Glyph& g = GlyphFor(text[k]);
    for (int row = 0; row < Canvas::kGlyphHeight; ++row) {
      for (int col = 0; col < Canvas::kGlyphWidth; ++col) {
        if (g.rows[row] & (1 << (Canvas::kGlyphWidth - 1 - col))) {
          f(static_cast<int>(k) * Canvas::kGlyphAdvance + col, row);
        }
      }
    }
  }
}

uint8_t Mix(uint8_t over, uint8_t under, double alpha) {
  return static_cast<uint8_t>(std::lround(alpha * over + (1.0 - alpha) * under));
}

}  // namespace

Canvas::Canvas(int width, int height, const Rgb& background) {
  image_.width = std::max(0, width);
  image_.height = std::max(0, height);
  image_.rgb.resize(static_cast<size_t>(image_.width) * static_cast<size_t>(image_.height) * 3);
  for (size_t i = 0; i < image_.rgb.size(); i += 3) {
    std::copy(background.begin(), background.end(), image_.rgb.begin() + static_cast<long>(i));
  }
}

Rgb Canvas::Get(int x, int y) const {
  const size_t i =
      (static_cast<size_t>(y) * static_cast<size_t>(image_.width) + static_cast<size_t>(x)) * 3;
  return {image_.rgb[i], image_.rgb[i + 1], image_.rgb[i + 2]};
}

void Canvas::Set(int64_t x, int64_t y, const Rgb& c) {
  if (x < 0 || y < 0 || x >= image_.width || y >= image_.height) return;
  const size_t i =
      (static_cast<size_t>(y) * static_cast<size_t>(image_.width) + static_cast<size_t>(x)) * 3;
  image_.rgb[i] = c[0];
  image_.rgb[i + 1] = c[1];
  image_.rgb[i + 2] = c[2];
}

void Canvas::Blend(int64_t x, int64_t y, const Rgb& c, double alpha) {
  if (x < 0 || y < 0 || x >= image_.width || y >= image_.height) return;
  alpha = std::isfinite(alpha) ? std::clamp(alpha, 0.0, 1.0) : 0.0;
  const Rgb under = Get(static_cast<int>(x), static_cast<int>(y));
  Set(x, y, {Mix(c[0], under[0], alpha), Mix(c[1], under[1], alpha), Mix(c[2], under[2], alpha)});
}

void Canvas::FillRect(int64_t x, int64_t y, int64_t w, int64_t h, const Rgb& c) {
  // Clipped first: a rectangle far outside (a trajectory point off the picture) costs nothing.
  const int64_t x0 = std::max<int64_t>(x, 0), y0 = std::max<int64_t>(y, 0);
  const int64_t x1 = std::min<int64_t>(x + w, image_.width);
  const int64_t y1 = std::min<int64_t>(y + h, image_.height);
  for (int64_t j = y0; j < y1; ++j) {
    for (int64_t i = x0; i < x1; ++i) Set(i, j, c);
  }
}

namespace {

/// Liang-Barsky: shortens the segment a-b to its part inside [lo, hi] on both axes; false when
/// no part is inside.
bool ClipSegment(double& ax, double& ay, double& bx, double& by, double lo_x, double lo_y,
                 double hi_x, double hi_y) {
  double t0 = 0.0, t1 = 1.0;
  const double dx = bx - ax, dy = by - ay;
  const double p[4] = {-dx, dx, -dy, dy};
  const double q[4] = {ax - lo_x, hi_x - ax, ay - lo_y, hi_y - ay};
  for (int k = 0; k < 4; ++k) {
    if (p[k] == 0.0) {
      if (q[k] < 0.0) return false;  // parallel to this edge and outside it
      continue;
    }
    const double t = q[k] / p[k];
    if (p[k] < 0.0) {
      t0 = std::max(t0, t);
    } else {
      t1 = std::min(t1, t);
    }
    if (t0 > t1) return false;
  }
  const double sx = ax, sy = ay;
  ax = sx + t0 * dx;
  ay = sy + t0 * dy;
  bx = sx + t1 * dx;
  by = sy + t1 * dy;
  return true;
}

}  // namespace

void Canvas::Line(int64_t x0, int64_t y0, int64_t x1, int64_t y1, int thickness, const Rgb& c) {
  // A segment reaching outside the picture (a trajectory wandering off the map) is first cut to
  // the picture and a margin of the pen's width, so that its cost is the pixels drawn. Segments
  // inside are walked exactly as given.
  const int64_t margin = std::max(thickness, 1) + 1;
  const auto outside = [&](int64_t x, int64_t y) {
    return x < -margin || y < -margin || x > image_.width + margin || y > image_.height + margin;
  };
  if (outside(x0, y0) || outside(x1, y1)) {
    auto ax = static_cast<double>(x0), ay = static_cast<double>(y0);
    auto bx = static_cast<double>(x1), by = static_cast<double>(y1);
    if (!ClipSegment(ax, ay, bx, by, static_cast<double>(-margin), static_cast<double>(-margin),
                     static_cast<double>(image_.width + margin),
                     static_cast<double>(image_.height + margin))) {
      return;
    }
    x0 = std::llround(ax);
    y0 = std::llround(ay);
    x1 = std::llround(bx);
    y1 = std::llround(by);
  }
  const int64_t dx = std::abs(x1 - x0), dy = -std::abs(y1 - y0);
  const int64_t sx = x0 < x1 ? 1 : -1, sy = y0 < y1 ? 1 : -1;
  const int64_t half = (thickness - 1) / 2;
  int64_t err = dx + dy;
  while (true) {
    FillRect(x0 - half, y0 - half, thickness, thickness, c);
    if (x0 == x1 && y0 == y1) break;
    const int64_t e2 = 2 * err;
    if (e2 >= dy) {
      err += dy;
      x0 += sx;
    }
    if (e2 <= dx) {
      err += dx;
      y0 += sy;
    }
  }
}

void Canvas::FillPolygon(const std::vector<PixelPoint>& points, const Rgb& c, double alpha) {
  if (points.size() < 3) return;
  double top = points[0].y, bottom = points[0].y;
  for (const PixelPoint& p : points) {
    if (!std::isfinite(p.x) || !std::isfinite(p.y)) return;
    top = std::min(top, p.y);
    bottom = std::max(bottom, p.y);
  }
  // Scan the rows whose centres can be inside, within the image.
  const auto first = static_cast<int>(std::max(0.0, std::floor(top)));
  const auto last =
      static_cast<int>(std::min(static_cast<double>(image_.height) - 1.0, std::ceil(bottom)));
  std::vector<double> crossings;
  for (int row = first; row <= last; ++row) {
    const double y = row + 0.5;
    crossings.clear();
    for (size_t i = 0; i < points.size(); ++i) {
      const PixelPoint& a = points[i];
      const PixelPoint& b = points[(i + 1) % points.size()];
      if ((a.y <= y) == (b.y <= y)) continue;  // the edge does not cross this row's centre
      crossings.push_back(a.x + (y - a.y) / (b.y - a.y) * (b.x - a.x));
    }
    std::sort(crossings.begin(), crossings.end());
    for (size_t k = 0; k + 1 < crossings.size(); k += 2) {
      // Pixels whose centre x + 0.5 lies in [crossings[k], crossings[k + 1]).
      const double from = std::max(0.0, std::ceil(crossings[k] - 0.5));
      const double to =
          std::min(static_cast<double>(image_.width), std::ceil(crossings[k + 1] - 0.5));
      for (auto x = static_cast<int64_t>(from); x < static_cast<int64_t>(to); ++x) {
        Blend(x, row, c, alpha);
      }
    }
  }
}

int Canvas::Text(int x, int y, const std::string& text, int size, const Rgb& c) {
  ForEachFontPixel(text,
                   [&](int u, int v) { FillRect(x + u * size, y + v * size, size, size, c); });
  return TextWidth(text, size);
}

int Canvas::TextUp(int x, int y, const std::string& text, int size, const Rgb& c) {
  // A quarter turn counter-clockwise: along the text goes up, down the glyph goes right.
  ForEachFontPixel(
      text, [&](int u, int v) { FillRect(x + v * size, y - (u + 1) * size, size, size, c); });
  return TextWidth(text, size);
}

int Canvas::TextWidth(const std::string& text, int size) {
  return static_cast<int>(text.size()) * kGlyphAdvance * size;
}

bool Canvas::HasGlyph(char c) { return FindGlyph(c) != nullptr; }

}  // namespace slam::io
