#pragma once
// A small raster canvas for pictures people look at (the map picture, the tuning plot): clipped
// pixels, lines, rectangles, translucent polygons and text in a 5x7 bitmap font.

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "engine/io/map_image.hpp"

namespace slam::io {

using Rgb = std::array<uint8_t, 3>;

/// A point in pixel coordinates (x right, y down; pixel (i, j) covers [i, i+1) x [j, j+1)).
struct PixelPoint {
  double x = 0.0;
  double y = 0.0;
};

/// An RGB image being drawn; every operation clips to the image.
class Canvas {
 public:
  /// The 5x7 font: glyph size and the horizontal advance per character, in font pixels.
  static constexpr int kGlyphWidth = 5;
  static constexpr int kGlyphHeight = 7;
  static constexpr int kGlyphAdvance = 6;

  /// A `width` x `height` image (negative sizes count as 0) filled with `background`.
  Canvas(int width, int height, const Rgb& background);

  int width() const { return image_.width; }
  int height() const { return image_.height; }

  /// The colour of pixel (x, y), which must be inside the image.
  Rgb Get(int x, int y) const;

  /// Sets one pixel; outside the image nothing happens.
  void Set(int64_t x, int64_t y, const Rgb& c);

  /// Mixes `c` over one pixel with opacity `alpha` (clamped to [0, 1]).
  void Blend(int64_t x, int64_t y, const Rgb& c, double alpha);

  /// Fills the w x h rectangle whose top-left pixel is (x, y).
  void FillRect(int64_t x, int64_t y, int64_t w, int64_t h, const Rgb& c);

  /// A line of `thickness` pixels between two pixel positions (Bresenham, square pen); what lies
  /// outside the image costs nothing, however far the ends are.
  void Line(int64_t x0, int64_t y0, int64_t x1, int64_t y1, int thickness, const Rgb& c);

  /// Fills a polygon (even-odd rule: a pixel is inside when its centre is) with opacity `alpha`,
  /// each pixel blended once. Polygons with fewer than 3 or non-finite points draw nothing.
  void FillPolygon(const std::vector<PixelPoint>& points, const Rgb& c, double alpha = 1.0);

  /// Text in the 5x7 font with its top-left corner at (x, y), each font pixel a `size` x `size`
  /// square; lower case is drawn as upper case, characters without a glyph as '?'. Returns the
  /// width, TextWidth(text, size).
  int Text(int x, int y, const std::string& text, int size, const Rgb& c);

  /// Text turned a quarter turn counter-clockwise (read bottom to top) whose bounding box has its
  /// bottom-left corner at (x, y); the box is 7 * size wide and TextWidth(text, size) high.
  int TextUp(int x, int y, const std::string& text, int size, const Rgb& c);

  /// The advance of `text` at `size`: 6 * size per character.
  static int TextWidth(const std::string& text, int size);

  /// Whether the font draws `c` itself rather than '?' (lower case counts as upper case).
  static bool HasGlyph(char c);

  const RgbImage& image() const { return image_; }
  RgbImage Take() { return std::move(image_); }

 private:
  RgbImage image_;
};

}  // namespace slam::io
