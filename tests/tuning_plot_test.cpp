// Tests of the Fig. 10-like tuning plot (offline/tuning_plot.hpp) and of the canvas it draws with
// (engine/io/canvas.hpp). The SVG is read back by a small XML parser written here, the axis is
// read from the SVG's own tick labels, and the PNG is decoded by libpng.

#include "offline/tuning_plot.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <limits>
#include <map>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "engine/io/canvas.hpp"
#include "tests/map_file_support.hpp"

namespace slam {
namespace {

namespace fs = std::filesystem;
using io::Canvas;
using io::Rgb;
using testing::CountColor;
using testing::Pixel;
using testing::ReadPng;

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr double kInf = std::numeric_limits<double>::infinity();

// ---------------------------------------------------------------------------------------------
// A minimal XML reader: tags must balance, attributes are double-quoted, entities are the five
// predefined ones.

struct Element {
  std::string name;
  std::map<std::string, std::string> attributes;
  std::string text;  // character data directly inside, entities decoded

  std::string Attr(const std::string& key) const {
    const auto it = attributes.find(key);
    return it == attributes.end() ? "" : it->second;
  }
  double Number(const std::string& key) const { return std::stod(Attr(key)); }
};

struct Xml {
  std::string error;              // empty when well formed
  std::vector<Element> elements;  // in document order, the root first

  std::vector<const Element*> WithClass(const std::string& cls) const {
    std::vector<const Element*> found;
    for (const Element& e : elements) {
      if (e.Attr("class") == cls) found.push_back(&e);
    }
    return found;
  }
};

bool Decode(const std::string& raw, std::string* out) {
  static const std::map<std::string, char> kEntities{
      {"amp", '&'}, {"lt", '<'}, {"gt", '>'}, {"quot", '"'}, {"apos", '\''}};
  out->clear();
  for (size_t i = 0; i < raw.size(); ++i) {
    if (raw[i] != '&') {
      *out += raw[i];
      continue;
    }
    const size_t semicolon = raw.find(';', i);
    if (semicolon == std::string::npos) return false;
    const auto it = kEntities.find(raw.substr(i + 1, semicolon - i - 1));
    if (it == kEntities.end()) return false;
    *out += it->second;
    i = semicolon;
  }
  return true;
}

Xml ParseXml(const std::string& text) {
  Xml xml;
  std::vector<size_t> open;
  size_t roots = 0;
  size_t i = 0;
  const auto fail = [&](const std::string& why) {
    xml.error = why + " at " + std::to_string(i);
    return xml;
  };
  const auto is_name = [](char c) {
    return std::isalnum(static_cast<unsigned char>(c)) || c == '-' || c == '_' || c == ':';
  };
  while (i < text.size()) {
    if (text[i] != '<') {
      const size_t next = std::min(text.find('<', i), text.size());
      std::string data;
      if (!Decode(text.substr(i, next - i), &data)) return fail("bad entity");
      if (open.empty()) {
        if (data.find_first_not_of(" \n\t\r") != std::string::npos)
          return fail("text outside root");
      } else {
        xml.elements[open.back()].text += data;
      }
      i = next;
      continue;
    }
    if (text.compare(i, 2, "<?") == 0) {
      const size_t end = text.find("?>", i);
      if (end == std::string::npos) return fail("unclosed declaration");
      i = end + 2;
      continue;
    }
    if (text.compare(i, 2, "</") == 0) {
      const size_t end = text.find('>', i);
      if (end == std::string::npos) return fail("unclosed end tag");
      const std::string name = text.substr(i + 2, end - i - 2);
      if (open.empty() || xml.elements[open.back()].name != name)
        return fail("unbalanced </" + name);
      open.pop_back();
      i = end + 1;
      continue;
    }
    Element e;
    ++i;
    while (i < text.size() && is_name(text[i])) e.name += text[i++];
    if (e.name.empty()) return fail("empty tag name");
    bool self_closing = false;
    while (true) {
      while (i < text.size() && std::isspace(static_cast<unsigned char>(text[i]))) ++i;
      if (i >= text.size()) return fail("unclosed tag");
      if (text.compare(i, 2, "/>") == 0) {
        self_closing = true;
        i += 2;
        break;
      }
      if (text[i] == '>') {
        ++i;
        break;
      }
      std::string key;
      while (i < text.size() && is_name(text[i])) key += text[i++];
      if (key.empty() || text.compare(i, 2, "=\"") != 0) return fail("bad attribute");
      const size_t end = text.find('"', i + 2);
      if (end == std::string::npos) return fail("unclosed attribute");
      const std::string raw = text.substr(i + 2, end - i - 2);
      if (raw.find('<') != std::string::npos) return fail("'<' in attribute");
      std::string value;
      if (!Decode(raw, &value)) return fail("bad entity in attribute");
      if (!e.attributes.emplace(key, value).second) return fail("repeated attribute");
      i = end + 1;
    }
    if (open.empty() && ++roots > 1) return fail("second root");
    xml.elements.push_back(std::move(e));
    if (!self_closing) open.push_back(xml.elements.size() - 1);
  }
  if (!open.empty()) return fail("unclosed <" + xml.elements[open.back()].name);
  if (roots != 1) return fail("no root");
  return xml;
}

struct Point {
  double x = 0.0;
  double y = 0.0;
};

std::vector<Point> ParsePoints(const std::string& text) {
  std::vector<Point> points;
  std::istringstream in(text);
  std::string pair;
  while (in >> pair) {
    const size_t comma = pair.find(',');
    points.push_back({std::stod(pair.substr(0, comma)), std::stod(pair.substr(comma + 1))});
  }
  return points;
}

/// An axis read from the SVG's tick labels: value <-> pixel through the first and last tick.
struct Axis {
  std::vector<double> values;
  std::vector<double> pixels;

  double Pixel(double v) const {
    return pixels.front() + (v - values.front()) * (pixels.back() - pixels.front()) /
                                (values.back() - values.front());
  }
};

Axis ReadAxis(const Xml& xml, const std::string& cls, const std::string& coordinate) {
  Axis axis;
  for (const Element* e : xml.WithClass(cls)) {
    axis.values.push_back(std::stod(e->text));
    axis.pixels.push_back(e->Number(coordinate));
  }
  return axis;
}

struct Area {
  double x0 = 0, y0 = 0, x1 = 0, y1 = 0;
  bool Contains(const Point& p) const {
    return p.x >= x0 - 1e-9 && p.x <= x1 + 1e-9 && p.y >= y0 - 1e-9 && p.y <= y1 + 1e-9;
  }
};

Area PlotArea(const Xml& xml) {
  const auto rects = xml.WithClass("plot-area");
  if (rects.size() != 1) return {};
  const Element& r = *rects[0];
  return {r.Number("x"), r.Number("y"), r.Number("x") + r.Number("width"),
          r.Number("y") + r.Number("height")};
}

std::string Hex(const Rgb& c) {
  char buffer[8];
  std::snprintf(buffer, sizeof(buffer), "#%02x%02x%02x", c[0], c[1], c[2]);
  return buffer;
}

/// A budget's run: the median falls from `start` to `end` like an evolution strategy converging,
/// the band narrows from `spread` to a third of it.
offline::TuningSeries Synthetic(const std::string& label, int generations, double start, double end,
                                double spread) {
  offline::TuningSeries s{label, {}};
  for (int g = 0; g < generations; ++g) {
    const double t = std::exp(-g / 8.0);
    const double median = end + (start - end) * t;
    const double half = spread * (1.0 + 2.0 * t) / 3.0;
    s.generations.push_back({median - half, median, median + half * 1.3});
  }
  return s;
}

std::vector<offline::TuningSeries> FourBudgets() {
  return {Synthetic("60 rays", 40, -0.5, -1.5, 0.3), Synthetic("120 rays", 40, -0.8, -2.5, 0.3),
          Synthetic("240 rays", 25, -1.0, -3.5, 0.3), Synthetic("480 rays", 0, 0, 0, 0)};
}

/// Checks the structure every plot must have; returns the parsed document.
Xml ExpectValidPlot(const std::string& svg, const std::vector<offline::TuningSeries>& series,
                    const offline::TuningPlotOptions& options) {
  Xml xml = ParseXml(svg);
  EXPECT_EQ(xml.error, "");
  if (!xml.error.empty()) return xml;
  const Element& root = xml.elements.front();
  EXPECT_EQ(root.name, "svg");
  EXPECT_EQ(root.Attr("width"), std::to_string(options.width));
  EXPECT_EQ(root.Attr("height"), std::to_string(options.height));
  // Every coordinate is a finite number.
  for (const Element& e : xml.elements) {
    for (const char* key : {"x", "y", "x1", "y1", "x2", "y2", "cx", "cy", "width", "height"}) {
      if (!e.Attr(key).empty()) {
        EXPECT_TRUE(std::isfinite(e.Number(key))) << e.name << " " << key;
      }
    }
    for (const Point& p : ParsePoints(e.Attr("points"))) {
      EXPECT_TRUE(std::isfinite(p.x) && std::isfinite(p.y)) << e.Attr("points");
    }
  }

  const Area area = PlotArea(xml);
  EXPECT_GT(area.x1 - area.x0, 100);
  EXPECT_GT(area.y1 - area.y0, 100);

  // One median polyline per series with a finite median, one point per such generation, in
  // increasing x, inside the plot area, in the series' colour.
  std::vector<size_t> drawn;
  for (size_t k = 0; k < series.size(); ++k) {
    size_t finite = 0;
    for (const offline::TuningBand& b : series[k].generations) finite += std::isfinite(b.median);
    if (finite > 0) drawn.push_back(k);
  }
  const auto medians = xml.WithClass("median");
  EXPECT_EQ(medians.size(), drawn.size());
  for (size_t i = 0; i < std::min(medians.size(), drawn.size()); ++i) {
    const size_t k = drawn[i];
    EXPECT_EQ(medians[i]->Attr("data-series"), std::to_string(k));
    EXPECT_EQ(medians[i]->Attr("stroke"), Hex(offline::TuningSeriesColor(k)));
    const std::vector<Point> points = ParsePoints(medians[i]->Attr("points"));
    size_t finite = 0;
    for (const offline::TuningBand& b : series[k].generations) finite += std::isfinite(b.median);
    EXPECT_EQ(points.size(), finite) << "series " << k;
    for (size_t p = 0; p < points.size(); ++p) {
      EXPECT_TRUE(area.Contains(points[p])) << "series " << k << " point " << p;
      if (p > 0) {
        EXPECT_GT(points[p].x, points[p - 1].x);
      }
    }
  }
  for (const Element* band : xml.WithClass("band")) {
    for (const Point& p : ParsePoints(band->Attr("points"))) EXPECT_TRUE(area.Contains(p));
  }

  // A legend line per series, y ticks increasing upwards, x ticks at whole generations.
  const auto legend = xml.WithClass("legend-label");
  EXPECT_EQ(legend.size(), series.size());
  for (size_t k = 0; k < std::min(legend.size(), series.size()); ++k) {
    EXPECT_EQ(legend[k]->text, series[k].label);
  }
  const Axis y = ReadAxis(xml, "y-tick", "y");
  EXPECT_GE(y.values.size(), 2u);
  for (size_t i = 1; i < y.values.size(); ++i) {
    EXPECT_GT(y.values[i], y.values[i - 1]);
    EXPECT_LT(y.pixels[i], y.pixels[i - 1]);
  }
  const Axis x = ReadAxis(xml, "x-tick", "x");
  EXPECT_GE(x.values.size(), 2u);
  for (size_t i = 0; i < x.values.size(); ++i) {
    EXPECT_EQ(x.values[i], std::round(x.values[i]));
    if (i > 0) {
      EXPECT_GT(x.pixels[i], x.pixels[i - 1]);
    }
  }
  return xml;
}

/// A fresh empty directory for one test's files.
std::string TestDir(const std::string& name) {
  const fs::path dir = fs::path(::testing::TempDir()) / ("tuning_plot_test_" + name);
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir.string();
}

/// The image as written to and read back from a PNG file.
io::RgbImage ThroughPng(const io::RgbImage& image, const std::string& name) {
  const std::string path = TestDir(name) + "/plot.png";
  EXPECT_TRUE(io::WritePng(path, image).ok());
  return ReadPng(path);
}

// ---------------------------------------------------------------------------------------------
// Canvas.

TEST(CanvasTest, PolygonFillsPixelsWhoseCentresAreInside) {
  Canvas canvas(20, 20, {255, 255, 255});
  const Rgb red{255, 0, 0};
  canvas.FillPolygon({{2, 3}, {12, 3}, {12, 13}, {2, 13}}, red);
  const io::RgbImage image = canvas.Take();
  EXPECT_EQ(CountColor(image, 0, 0, 20, 20, red), 100);
  EXPECT_EQ(CountColor(image, 2, 3, 12, 13, red), 100);

  // A right triangle with legs of 10 px covers about 50 pixels; the outline clips to the image.
  Canvas triangle(20, 20, {255, 255, 255});
  triangle.FillPolygon({{0, 0}, {10, 0}, {0, 10}}, red);
  const int n = CountColor(triangle.image(), 0, 0, 20, 20, red);
  EXPECT_GE(n, 45);
  EXPECT_LE(n, 55);
  Canvas clipped(8, 8, {255, 255, 255});
  clipped.FillPolygon({{-100, -100}, {100, -100}, {100, 100}, {-100, 100}}, red);
  EXPECT_EQ(CountColor(clipped.image(), 0, 0, 8, 8, red), 64);
}

TEST(CanvasTest, TranslucentFillBlendsOnceAndDegeneratePolygonsDrawNothing) {
  Canvas canvas(10, 10, {255, 255, 255});
  canvas.FillPolygon({{0, 0}, {10, 0}, {10, 10}, {0, 10}}, {0, 0, 0}, 0.5);
  EXPECT_EQ(canvas.Get(5, 5), (Rgb{128, 128, 128}));
  canvas.Blend(1, 1, {0, 0, 0}, 0.5);
  EXPECT_EQ(canvas.Get(1, 1), (Rgb{64, 64, 64}));
  canvas.Blend(2, 2, {0, 0, 0}, kNaN);
  EXPECT_EQ(canvas.Get(2, 2), (Rgb{128, 128, 128}));

  const io::RgbImage before = canvas.image();
  canvas.FillPolygon({{0, 0}, {10, 10}}, {0, 0, 0});
  canvas.FillPolygon({{0, 0}, {10, 0}, {0, 10}, {kNaN, 5}}, {0, 0, 0});
  canvas.FillPolygon({{0, 5}, {10, 5}, {5, 5}}, {0, 0, 0});  // no area
  canvas.Blend(-1, 3, {0, 0, 0}, 1.0);
  canvas.Blend(3, 10, {0, 0, 0}, 1.0);
  EXPECT_EQ(canvas.image().rgb, before.rgb);
}

TEST(CanvasTest, UpwardTextIsTheTextTurnedAQuarterCounterClockwise) {
  const Rgb ink{0, 0, 0};
  Canvas flat(40, 40, {255, 255, 255});
  EXPECT_EQ(flat.Text(0, 0, "L1", 2, ink), 24);
  Canvas up(40, 40, {255, 255, 255});
  EXPECT_EQ(up.TextUp(0, 24, "L1", 2, ink), 24);
  // Pixel (u, v) of the flat text lands at (v, 23 - u).
  for (int v = 0; v < 14; ++v) {
    for (int u = 0; u < 24; ++u) {
      EXPECT_EQ(flat.Get(u, v), up.Get(v, 23 - u)) << u << "," << v;
    }
  }
  EXPECT_EQ(CountColor(up.image(), 14, 0, 40, 40, ink), 0);
}

TEST(CanvasTest, FontHasEveryCharacterThePlotDraws) {
  const offline::TuningPlotOptions defaults;
  for (const std::string& text :
       {defaults.title, defaults.x_label, defaults.y_label, std::string("0123456789-.=(),")}) {
    for (const char c : text) EXPECT_TRUE(Canvas::HasGlyph(c)) << "'" << c << "' in " << text;
  }
  EXPECT_FALSE(Canvas::HasGlyph('<'));
  // '=' is two bars, not the '?' of missing glyphs.
  Canvas a(6, 7, {255, 255, 255}), b(6, 7, {255, 255, 255});
  a.Text(0, 0, "=", 1, {0, 0, 0});
  b.Text(0, 0, "?", 1, {0, 0, 0});
  EXPECT_EQ(CountColor(a.image(), 0, 0, 6, 7, {0, 0, 0}), 10);
  EXPECT_NE(a.image().rgb, b.image().rgb);
}

// ---------------------------------------------------------------------------------------------
// SVG.

TEST(TuningPlotSvgTest, OneBandAndMedianPerSeriesWithALegend) {
  const std::vector<offline::TuningSeries> series = FourBudgets();
  const offline::TuningPlotOptions options;
  const std::string svg = offline::TuningPlotSvg(series, options);
  const Xml xml = ExpectValidPlot(svg, series, options);
  ASSERT_EQ(xml.error, "");
  EXPECT_EQ(xml.WithClass("median").size(), 3u);  // "480 rays" has not started
  EXPECT_EQ(xml.WithClass("band").size(), 3u);
  ASSERT_EQ(xml.WithClass("title").size(), 1u);
  EXPECT_EQ(xml.WithClass("title")[0]->text, options.title);
  EXPECT_EQ(xml.WithClass("y-label")[0]->text, options.y_label);
  EXPECT_EQ(xml.WithClass("x-label")[0]->text, options.x_label);
  // The band outline goes along q3 and back along q1: twice the generations.
  EXPECT_EQ(ParsePoints(xml.WithClass("band")[2]->Attr("points")).size(), 50u);
  std::set<std::string> colors;
  for (size_t k = 0; k < 8; ++k) colors.insert(Hex(offline::TuningSeriesColor(k)));
  EXPECT_EQ(colors.size(), 8u);
  EXPECT_EQ(offline::TuningSeriesColor(8), offline::TuningSeriesColor(0));
}

TEST(TuningPlotSvgTest, YAxisCoversEveryQuartileWithNiceTicks) {
  const std::vector<offline::TuningSeries> series = FourBudgets();
  const Xml xml = ParseXml(offline::TuningPlotSvg(series));
  ASSERT_EQ(xml.error, "");
  double lo = kInf, hi = -kInf;
  for (const offline::TuningSeries& s : series) {
    for (const offline::TuningBand& b : s.generations) {
      lo = std::min(lo, b.q1);
      hi = std::max(hi, b.q3);
    }
  }
  const Axis y = ReadAxis(xml, "y-tick", "y");
  ASSERT_GE(y.values.size(), 3u);
  EXPECT_LT(y.values.front(), lo);
  EXPECT_GT(y.values.back(), hi);
  const double step = y.values[1] - y.values[0];
  const double mantissa = step / std::pow(10.0, std::floor(std::log10(step)));
  EXPECT_TRUE(std::abs(mantissa - 1) < 1e-6 || std::abs(mantissa - 2) < 1e-6 ||
              std::abs(mantissa - 5) < 1e-6)
      << step;
  for (size_t i = 1; i < y.values.size(); ++i) {
    EXPECT_NEAR(y.values[i] - y.values[i - 1], step, 1e-9);
    EXPECT_NEAR(y.values[i] / step, std::round(y.values[i] / step), 1e-6);
  }
  // Generations 1 .. 40 (numbered as slam-tune's console and table3.md number them): integer
  // ticks from 1, none past the last generation.
  const Axis x = ReadAxis(xml, "x-tick", "x");
  EXPECT_EQ(x.values.front(), 1.0);
  EXPECT_LE(x.values.back(), 40.0);
  EXPECT_GE(x.values.size(), 3u);
}

TEST(TuningPlotSvgTest, MedianMapsThroughTheAxis) {
  // Known medians: -1 at generation 1, -3 at generation 11, -2 elsewhere; 21 generations.
  offline::TuningSeries s{"known", {}};
  for (int g = 0; g <= 20; ++g) {
    const double m = g == 0 ? -1.0 : (g == 10 ? -3.0 : -2.0);
    s.generations.push_back({m - 0.25, m, m + 0.25});
  }
  const Xml xml = ParseXml(offline::TuningPlotSvg({s}));
  ASSERT_EQ(xml.error, "");
  const Axis x = ReadAxis(xml, "x-tick", "x");
  const Axis y = ReadAxis(xml, "y-tick", "y");
  const std::vector<Point> points = ParsePoints(xml.WithClass("median")[0]->Attr("points"));
  ASSERT_EQ(points.size(), 21u);
  EXPECT_NEAR(points[0].x, x.Pixel(1), 0.01);
  EXPECT_NEAR(points[10].x, x.Pixel(11), 0.01);
  EXPECT_NEAR(points[20].x, x.Pixel(21), 0.01);
  EXPECT_NEAR(points[0].y, y.Pixel(-1.0), 0.01);
  EXPECT_NEAR(points[10].y, y.Pixel(-3.0), 0.01);
  EXPECT_NEAR(points[5].y, y.Pixel(-2.0), 0.01);
  EXPECT_LT(points[0].y, points[5].y);  // lower fitness is further down
}

TEST(TuningPlotSvgTest, EscapesLabelsAndTitles) {
  offline::TuningPlotOptions options;
  options.title = "<script>alert('x')</script> & co";
  options.y_label = "e \"quoted\"";
  const std::vector<offline::TuningSeries> series{
      {"rays < 200 & > 100", {{-1, -0.5, 0}, {-2, -1, 0}}}};
  const std::string svg = offline::TuningPlotSvg(series, options);
  EXPECT_EQ(svg.find("<script>"), std::string::npos);
  EXPECT_EQ(svg.find("< 200"), std::string::npos);
  EXPECT_NE(svg.find("rays &lt; 200 &amp; &gt; 100"), std::string::npos);
  const Xml xml = ExpectValidPlot(svg, series, options);
  ASSERT_EQ(xml.error, "");
  EXPECT_EQ(xml.WithClass("title")[0]->text, options.title);
  EXPECT_EQ(xml.WithClass("y-label")[0]->text, options.y_label);
  EXPECT_EQ(xml.WithClass("legend-label")[0]->text, series[0].label);
}

TEST(TuningPlotSvgTest, DegenerateInputsGiveValidPlots) {
  const offline::TuningPlotOptions options;
  // Nothing at all, and a run not started.
  ExpectValidPlot(offline::TuningPlotSvg({}, options), {}, options);
  const std::vector<offline::TuningSeries> not_started{{"60 rays", {}}};
  ExpectValidPlot(offline::TuningPlotSvg(not_started, options), not_started, options);

  // One generation: a one-point median with a marker, a band bar.
  const std::vector<offline::TuningSeries> one{{"one", {{-1.2, -1.0, -0.9}}}};
  const Xml one_xml = ExpectValidPlot(offline::TuningPlotSvg(one, options), one, options);
  EXPECT_EQ(one_xml.WithClass("marker").size(), 1u);
  ASSERT_EQ(one_xml.WithClass("band").size(), 1u);
  const std::vector<Point> bar = ParsePoints(one_xml.WithClass("band")[0]->Attr("points"));
  ASSERT_EQ(bar.size(), 4u);
  EXPECT_GE(std::abs(bar[1].x - bar[0].x), 3.0);
  EXPECT_NEAR(std::abs(bar[2].y - bar[1].y),
              std::abs(ReadAxis(one_xml, "y-tick", "y").Pixel(-1.2) -
                       ReadAxis(one_xml, "y-tick", "y").Pixel(-0.9)),
              0.02);

  // Flat: every value equal; the line lies strictly inside the plot, between two ticks.
  const std::vector<offline::TuningSeries> flat{
      {"flat", std::vector<offline::TuningBand>(12, {-1.5, -1.5, -1.5})}};
  const Xml flat_xml = ExpectValidPlot(offline::TuningPlotSvg(flat, options), flat, options);
  const Area area = PlotArea(flat_xml);
  const Axis y = ReadAxis(flat_xml, "y-tick", "y");
  EXPECT_LT(y.values.front(), -1.5);
  EXPECT_GT(y.values.back(), -1.5);
  for (const Point& p : ParsePoints(flat_xml.WithClass("median")[0]->Attr("points"))) {
    EXPECT_GT(p.y, area.y0 + 10);
    EXPECT_LT(p.y, area.y1 - 10);
    EXPECT_NEAR(p.y, y.Pixel(-1.5), 0.01);
  }
  // Zero is flat too.
  const std::vector<offline::TuningSeries> zero{
      {"zero", std::vector<offline::TuningBand>(3, {0, 0, 0})}};
  ExpectValidPlot(offline::TuningPlotSvg(zero, options), zero, options);

  // Non-finite values are skipped: the axis ignores them and the points stay in increasing x.
  const std::vector<offline::TuningSeries> holes{
      {"holes",
       {{-2, -1.5, -1}, {kNaN, kNaN, kNaN}, {-2, kInf, -1}, {kNaN, -1.4, -1}, {-1.9, -1.3, -0.8}}},
      {"all missing", {{kNaN, kNaN, kNaN}, {-kInf, kNaN, kInf}}}};
  const Xml holes_xml = ExpectValidPlot(offline::TuningPlotSvg(holes, options), holes, options);
  EXPECT_EQ(holes_xml.WithClass("median").size(), 1u);
  const Axis hy = ReadAxis(holes_xml, "y-tick", "y");
  EXPECT_LT(hy.values.front(), -2.0);
  EXPECT_GT(hy.values.back(), -0.8);
  EXPECT_LT(hy.values.back() - hy.values.front(), 3.0);

  // A small canvas is still a plot.
  offline::TuningPlotOptions small;
  small.width = 320;
  small.height = 240;
  ExpectValidPlot(offline::TuningPlotSvg(FourBudgets(), small), FourBudgets(), small);
}

// ---------------------------------------------------------------------------------------------
// PNG.

TEST(TuningPlotImageTest, PngHasTheSizeTheSeriesColoursAndMediansWhereTheAxisPutsThem) {
  offline::TuningPlotOptions options;
  options.width = 800;
  options.height = 500;
  const std::vector<offline::TuningSeries> series = FourBudgets();
  const io::RgbImage image = ThroughPng(offline::TuningPlotImage(series, options), "colours");
  ASSERT_EQ(image.width, 800);
  ASSERT_EQ(image.height, 500);

  const Xml xml = ParseXml(offline::TuningPlotSvg(series, options));
  ASSERT_EQ(xml.error, "");
  const Area area = PlotArea(xml);
  const Axis x = ReadAxis(xml, "x-tick", "x");
  const Axis y = ReadAxis(xml, "y-tick", "y");
  const auto x0 = static_cast<int>(area.x0), x1 = static_cast<int>(area.x1);
  const auto y0 = static_cast<int>(area.y0), y1 = static_cast<int>(area.y1);
  for (size_t k = 0; k < 3; ++k) {
    EXPECT_GT(CountColor(image, x0, y0, x1, y1, offline::TuningSeriesColor(k)), 100) << k;
  }
  // The series not started is only in the legend.
  EXPECT_EQ(CountColor(image, x0, y0, x1, y1, offline::TuningSeriesColor(3)), 0);
  EXPECT_GT(CountColor(image, x1, 0, image.width, image.height, offline::TuningSeriesColor(3)), 0);

  // At generation 31 the medians are apart: each column holds its line within 2 px of the axis.
  for (size_t k = 0; k < 2; ++k) {
    const offline::TuningBand& b = series[k].generations[30];
    const auto column = static_cast<int>(std::lround(x.Pixel(31)));
    int sum = 0, n = 0;
    for (int row = y0; row < y1; ++row) {
      if (Pixel(image, column, row) == offline::TuningSeriesColor(k)) {
        sum += row;
        ++n;
      }
    }
    ASSERT_GT(n, 0) << k;
    EXPECT_NEAR(static_cast<double>(sum) / n + 0.5, y.Pixel(b.median), 2.0) << k;

    // Between the median and q1 the band is the series' colour a quarter over the background.
    const auto band_row = static_cast<int>(std::lround((y.Pixel(b.median) + y.Pixel(b.q1)) / 2));
    ASSERT_GT(y.Pixel(b.q1) - y.Pixel(b.median), 8.0);
    const auto p = Pixel(image, column, band_row);
    const Rgb c = offline::TuningSeriesColor(k);
    EXPECT_NE(p, c);
    EXPECT_NE(p, (Rgb{255, 255, 255}));
    for (size_t ch = 0; ch < 3; ++ch) {
      const double over_white = 0.25 * c[ch] + 0.75 * 255, over_grid = 0.25 * c[ch] + 0.75 * 225;
      EXPECT_TRUE(std::abs(p[ch] - over_white) <= 1 || std::abs(p[ch] - over_grid) <= 1)
          << k << " channel " << ch << ": " << int{p[ch]};
    }
  }
}

TEST(TuningPlotImageTest, DegenerateInputsRender) {
  offline::TuningPlotOptions options;
  options.width = 640;
  options.height = 400;
  const std::vector<std::vector<offline::TuningSeries>> cases{
      {},
      {{"60 rays", {}}},
      {{"one", {{-1.2, -1.0, -0.9}}}},
      {{"flat", std::vector<offline::TuningBand>(12, {-1.5, -1.5, -1.5})}},
      {{"nan", {{kNaN, kNaN, kNaN}, {-2, -1.5, -1}, {kNaN, kInf, -kInf}, {-2, -1.4, -1}}}},
  };
  for (size_t i = 0; i < cases.size(); ++i) {
    const io::RgbImage image =
        ThroughPng(offline::TuningPlotImage(cases[i], options), "degenerate" + std::to_string(i));
    ASSERT_EQ(image.width, 640) << i;
    ASSERT_EQ(image.height, 400) << i;
    const Area area = PlotArea(ParseXml(offline::TuningPlotSvg(cases[i], options)));
    // Left of the legend.
    const int in_plot = CountColor(image, 0, 0, static_cast<int>(area.x1), image.height,
                                   offline::TuningSeriesColor(0));
    if (i >= 2) {
      EXPECT_GT(in_plot, 20) << i;  // the marker or the line
    } else {
      EXPECT_EQ(in_plot, 0) << i;
    }
  }
}

}  // namespace
}  // namespace slam
