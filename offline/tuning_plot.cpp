#include "offline/tuning_plot.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <iterator>
#include <limits>

#include "engine/io/canvas.hpp"

namespace slam::offline {
namespace {

using io::Canvas;
using io::PixelPoint;
using io::Rgb;

// Okabe & Ito (2008), "Color Universal Design": distinguishable with every common colour-vision
// deficiency. Black comes last since axes and text are dark.
constexpr Rgb kPalette[] = {
    {0, 114, 178},    // blue
    {213, 94, 0},     // vermillion
    {0, 158, 115},    // bluish green
    {230, 159, 0},    // orange
    {204, 121, 167},  // reddish purple
    {86, 180, 233},   // sky blue
    {240, 228, 66},   // yellow
    {0, 0, 0},        // black
};
constexpr Rgb kBackground{255, 255, 255};
constexpr Rgb kInk{51, 51, 51};
constexpr Rgb kGridLine{225, 225, 225};
constexpr double kBandAlpha = 0.25;

// Layout in pixels, shared by the SVG and the raster. The raster font is the 5x7 font at 2 pixels
// per font pixel: 12 px per character, 14 px high.
constexpr int kFontSize = 2;
constexpr int kCharWidth = Canvas::kGlyphAdvance * kFontSize;
constexpr int kTextHeight = Canvas::kGlyphHeight * kFontSize;
constexpr int kPad = 12;
constexpr int kTick = 5;
constexpr int kSwatch = 24;
constexpr int kLegendRow = 22;
constexpr int kMedianWidth = 2;
constexpr double kValueLimit = 1e12;  // larger finite values are clamped to it

/// Rounds `raw` > 0 up to 1, 2 or 5 x 10^k.
double NiceStep(double raw) {
  const double magnitude = std::pow(10.0, std::floor(std::log10(raw)));
  for (const double m : {1.0, 2.0, 5.0}) {
    if (raw <= m * magnitude * (1.0 + 1e-9)) return m * magnitude;
  }
  return 10.0 * magnitude;
}

std::string FormatFixed(double v, int decimals) {
  char buffer[64];
  std::snprintf(buffer, sizeof(buffer), "%.*f", decimals, v);
  return buffer;
}

/// An SVG coordinate.
std::string Num(double v) { return FormatFixed(v, 2); }

std::string Hex(const Rgb& c) {
  char buffer[8];
  std::snprintf(buffer, sizeof(buffer), "#%02x%02x%02x", c[0], c[1], c[2]);
  return buffer;
}

/// Text as XML character data or attribute value; control characters XML forbids become '?'.
std::string Escape(const std::string& text) {
  std::string out;
  for (const char c : text) {
    switch (c) {
      case '&':
        out += "&amp;";
        break;
      case '<':
        out += "&lt;";
        break;
      case '>':
        out += "&gt;";
        break;
      case '"':
        out += "&quot;";
        break;
      case '\'':
        out += "&apos;";
        break;
      default:
        out +=
            (static_cast<unsigned char>(c) < 0x20 && c != '\t' && c != '\n' && c != '\r') ? '?' : c;
    }
  }
  return out;
}

struct Tick {
  double pixel = 0.0;
  std::string text;
};

/// Where everything goes: the plot area, the axes' ranges and ticks, the legend's corner.
struct Layout {
  int width = 0;
  int height = 0;
  int left = 0, top = 0, right = 0, bottom = 0;  // plot area
  double x_max = 2.0;                            // generations run from 1 to x_max
  double y_min = 0.0, y_max = 1.0;
  std::vector<Tick> x_ticks, y_ticks;
  int legend_x = 0;

  /// The pixel column of a generation numbered from 1, as slam-tune's console and table3.md
  /// number them.
  double X(double generation) const {
    return left + (generation - 1.0) / (x_max - 1.0) * (right - left);
  }
  /// The pixel column of a series' `index`-th generation (0-based).
  double XOfIndex(size_t index) const { return X(static_cast<double>(index) + 1.0); }
  double Y(double fitness) const {
    const double v = std::clamp(fitness, y_min, y_max);
    return bottom - (v - y_min) / (y_max - y_min) * (bottom - top);
  }
};

bool Finite(double v) { return std::isfinite(v); }

Layout MakeLayout(const std::vector<TuningSeries>& series, const TuningPlotOptions& options) {
  Layout layout;
  layout.width = std::clamp(options.width, 240, 8192);
  layout.height = std::clamp(options.height, 180, 8192);

  // The data: the longest series and the range of every finite value.
  size_t generations = 0;
  double lo = std::numeric_limits<double>::infinity(), hi = -lo;
  size_t longest_label = 0;
  for (const TuningSeries& s : series) {
    generations = std::max(generations, s.generations.size());
    longest_label = std::max(longest_label, s.label.size());
    for (const TuningBand& b : s.generations) {
      for (const double v : {b.q1, b.median, b.q3}) {
        if (!Finite(v)) continue;
        lo = std::min(lo, std::clamp(v, -kValueLimit, kValueLimit));
        hi = std::max(hi, std::clamp(v, -kValueLimit, kValueLimit));
      }
    }
  }
  if (lo > hi) {  // nothing to show
    lo = 0.0;
    hi = 1.0;
  }
  // A margin of 5% of the range each side; a flat range gets one around its value.
  const double span = hi - lo;
  const bool flat = span <= 1e-9 * std::max({1.0, std::abs(lo), std::abs(hi)});
  const double margin = flat ? std::max(0.05 * std::abs(hi), 0.05) : 0.05 * span;

  // Rows: title, plot, x tick labels and x label.
  layout.top = options.title.empty() ? kPad + kTextHeight / 2 : 2 * kPad + kTextHeight;
  layout.bottom = layout.height - (kTick + 6 + kTextHeight + 10 + kTextHeight + kPad);
  const int plot_height = layout.bottom - layout.top;

  // The y axis: 1, 2 or 5 x 10^k steps, about one per 50 px.
  const double target_y_ticks = std::clamp(plot_height / 50, 2, 8);
  const double y_step = NiceStep((span + 2.0 * margin) / target_y_ticks);
  layout.y_min = std::floor((lo - margin) / y_step) * y_step;
  layout.y_max = std::ceil((hi + margin) / y_step) * y_step;
  if (!(layout.y_max > layout.y_min)) layout.y_max = layout.y_min + 1.0;
  const int decimals = std::clamp(static_cast<int>(-std::floor(std::log10(y_step))), 0, 12);
  const auto y_count = static_cast<int>(std::lround((layout.y_max - layout.y_min) / y_step));
  std::vector<double> y_values;
  for (int i = 0; i <= std::min(y_count, 40); ++i) {
    double v = layout.y_min + i * y_step;
    if (std::abs(v) < 1e-6 * y_step) v = 0.0;  // no "-0.00"
    y_values.push_back(v);
  }
  size_t y_label_chars = 1;
  for (const double v : y_values)
    y_label_chars = std::max(y_label_chars, FormatFixed(v, decimals).size());

  // Columns: y label, y tick labels, plot, legend.
  const int label_column = options.y_label.empty() ? 0 : kTextHeight + 10;
  layout.left =
      std::min(kPad + label_column + static_cast<int>(y_label_chars) * kCharWidth + 6 + kTick,
               layout.width * 2 / 5);
  const int legend_width =
      series.empty() ? 2 * kPad
                     : kPad + kSwatch + 8 + static_cast<int>(longest_label) * kCharWidth + kPad;
  layout.right = layout.width - std::min(legend_width, layout.width * 2 / 5);
  layout.legend_x = layout.right + kPad;

  for (const double v : y_values) layout.y_ticks.push_back({layout.Y(v), FormatFixed(v, decimals)});

  // The x axis: generations 1 .. n, ticks at 1 and at whole multiples of a nice step, about one
  // per 70 px.
  layout.x_max = std::max(2.0, static_cast<double>(generations));
  const double target_x_ticks = std::clamp((layout.right - layout.left) / 70, 2, 10);
  const double x_step = std::max(1.0, NiceStep((layout.x_max - 1.0) / target_x_ticks));
  layout.x_ticks.push_back({layout.X(1.0), "1"});
  for (double g = x_step; g <= layout.x_max + 1e-9; g += x_step) {
    if (g > 1.0) layout.x_ticks.push_back({layout.X(g), FormatFixed(g, 0)});
  }
  return layout;
}

/// The interquartile band of one series as a closed outline (q3 forward, q1 back); a single
/// generation gives a bar up to 6 px wide inside the plot area. Empty when no generation has both
/// quartiles.
std::vector<PixelPoint> BandOutline(const TuningSeries& s, const Layout& layout) {
  std::vector<PixelPoint> upper, lower;
  for (size_t g = 0; g < s.generations.size(); ++g) {
    const TuningBand& b = s.generations[g];
    if (!Finite(b.q1) || !Finite(b.q3)) continue;
    const double x = layout.XOfIndex(g);
    upper.push_back({x, layout.Y(std::max(b.q1, b.q3))});
    lower.push_back({x, layout.Y(std::min(b.q1, b.q3))});
  }
  if (upper.size() == 1) {
    const double x0 = std::max<double>(upper[0].x - 3, layout.left);
    const double x1 = std::min<double>(upper[0].x + 3, layout.right);
    return {{x0, upper[0].y}, {x1, upper[0].y}, {x1, lower[0].y}, {x0, lower[0].y}};
  }
  upper.insert(upper.end(), lower.rbegin(), lower.rend());
  return upper;
}

/// The median of one series at every generation where it is finite.
std::vector<PixelPoint> MedianLine(const TuningSeries& s, const Layout& layout) {
  std::vector<PixelPoint> points;
  for (size_t g = 0; g < s.generations.size(); ++g) {
    const double m = s.generations[g].median;
    if (Finite(m)) points.push_back({layout.XOfIndex(g), layout.Y(m)});
  }
  return points;
}

std::string Points(const std::vector<PixelPoint>& points) {
  std::string text;
  for (const PixelPoint& p : points) {
    if (!text.empty()) text += ' ';
    text += Num(p.x) + "," + Num(p.y);
  }
  return text;
}

/// The top-left pixel of a `pen` x `pen` square centred on p.
int64_t PenCorner(double v, int pen) { return std::lround(v - pen / 2.0); }

}  // namespace

std::array<uint8_t, 3> TuningSeriesColor(size_t index) {
  return kPalette[index % std::size(kPalette)];
}

std::string TuningPlotSvg(const std::vector<TuningSeries>& series,
                          const TuningPlotOptions& options) {
  const Layout layout = MakeLayout(series, options);
  const std::string w = std::to_string(layout.width), h = std::to_string(layout.height);
  std::string svg = "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n";
  svg += "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"" + w + "\" height=\"" + h +
         "\" viewBox=\"0 0 " + w + " " + h +
         "\" font-family=\"sans-serif\" font-size=\"13\" fill=\"" + Hex(kInk) + "\">\n";
  svg += "<rect width=\"" + w + "\" height=\"" + h + "\" fill=\"" + Hex(kBackground) + "\"/>\n";
  if (!options.title.empty()) {
    svg += "<text class=\"title\" x=\"" + Num(layout.width / 2.0) + "\" y=\"" +
           Num(kPad + kTextHeight / 2.0) +
           "\" text-anchor=\"middle\" dominant-baseline=\"middle\" font-size=\"16\">" +
           Escape(options.title) + "</text>\n";
  }

  // Grid lines, ticks and tick labels.
  const std::string left = Num(layout.left), right = Num(layout.right);
  const std::string top = Num(layout.top), bottom = Num(layout.bottom);
  svg += "<g class=\"grid\" stroke=\"" + Hex(kGridLine) + "\" stroke-width=\"1\">\n";
  for (const Tick& t : layout.y_ticks) {
    svg += "<line x1=\"" + left + "\" y1=\"" + Num(t.pixel) + "\" x2=\"" + right + "\" y2=\"" +
           Num(t.pixel) + "\"/>\n";
  }
  svg += "</g>\n<g class=\"y-ticks\">\n";
  for (const Tick& t : layout.y_ticks) {
    svg += "<line x1=\"" + Num(layout.left - kTick) + "\" y1=\"" + Num(t.pixel) + "\" x2=\"" +
           left + "\" y2=\"" + Num(t.pixel) + "\" stroke=\"" + Hex(kInk) + "\"/>\n";
    svg += "<text class=\"y-tick\" x=\"" + Num(layout.left - kTick - 4) + "\" y=\"" + Num(t.pixel) +
           "\" text-anchor=\"end\" dominant-baseline=\"middle\">" + t.text + "</text>\n";
  }
  svg += "</g>\n<g class=\"x-ticks\">\n";
  for (const Tick& t : layout.x_ticks) {
    svg += "<line x1=\"" + Num(t.pixel) + "\" y1=\"" + bottom + "\" x2=\"" + Num(t.pixel) +
           "\" y2=\"" + Num(layout.bottom + kTick) + "\" stroke=\"" + Hex(kInk) + "\"/>\n";
    svg += "<text class=\"x-tick\" x=\"" + Num(t.pixel) + "\" y=\"" +
           Num(layout.bottom + kTick + 6 + kTextHeight / 2.0) +
           "\" text-anchor=\"middle\" dominant-baseline=\"middle\">" + t.text + "</text>\n";
  }
  svg += "</g>\n";
  if (!options.x_label.empty()) {
    svg += "<text class=\"x-label\" x=\"" + Num((layout.left + layout.right) / 2.0) + "\" y=\"" +
           Num(layout.height - kPad - kTextHeight / 2.0) +
           "\" text-anchor=\"middle\" dominant-baseline=\"middle\">" + Escape(options.x_label) +
           "</text>\n";
  }
  if (!options.y_label.empty()) {
    const std::string x = Num(kPad + kTextHeight / 2.0);
    const std::string y = Num((layout.top + layout.bottom) / 2.0);
    svg += "<text class=\"y-label\" transform=\"translate(" + x + "," + y +
           ") rotate(-90)\" text-anchor=\"middle\" dominant-baseline=\"middle\">" +
           Escape(options.y_label) + "</text>\n";
  }

  // Bands, the frame, then the medians over both.
  svg += "<g class=\"bands\" stroke=\"none\" fill-opacity=\"" + Num(kBandAlpha) + "\">\n";
  for (size_t k = 0; k < series.size(); ++k) {
    const std::vector<PixelPoint> band = BandOutline(series[k], layout);
    if (band.empty()) continue;
    svg += "<polygon class=\"band\" data-series=\"" + std::to_string(k) + "\" fill=\"" +
           Hex(TuningSeriesColor(k)) + "\" points=\"" + Points(band) + "\"/>\n";
  }
  svg += "</g>\n";
  svg += "<rect class=\"plot-area\" x=\"" + left + "\" y=\"" + top + "\" width=\"" +
         Num(layout.right - layout.left) + "\" height=\"" + Num(layout.bottom - layout.top) +
         "\" fill=\"none\" stroke=\"" + Hex(kInk) + "\"/>\n";
  svg += "<g class=\"medians\" fill=\"none\" stroke-width=\"" + std::to_string(kMedianWidth) +
         "\" stroke-linejoin=\"round\">\n";
  for (size_t k = 0; k < series.size(); ++k) {
    const std::vector<PixelPoint> median = MedianLine(series[k], layout);
    if (median.empty()) continue;
    const std::string color = Hex(TuningSeriesColor(k));
    svg += "<polyline class=\"median\" data-series=\"" + std::to_string(k) + "\" stroke=\"" +
           color + "\" points=\"" + Points(median) + "\"/>\n";
    if (median.size() == 1) {  // a lone point draws no line
      svg += "<circle class=\"marker\" cx=\"" + Num(median[0].x) + "\" cy=\"" + Num(median[0].y) +
             "\" r=\"3\" fill=\"" + color + "\" stroke=\"none\"/>\n";
    }
  }
  svg += "</g>\n";

  // Legend: a swatch (band and median) and the label per series.
  svg += "<g class=\"legend\">\n";
  for (size_t k = 0; k < series.size(); ++k) {
    const double y = layout.top + static_cast<double>(k) * kLegendRow;
    const std::string color = Hex(TuningSeriesColor(k));
    svg += "<rect x=\"" + Num(layout.legend_x) + "\" y=\"" + Num(y + 4) + "\" width=\"" +
           std::to_string(kSwatch) + "\" height=\"12\" fill=\"" + color + "\" fill-opacity=\"" +
           Num(kBandAlpha) + "\"/>\n";
    svg += "<line x1=\"" + Num(layout.legend_x) + "\" y1=\"" + Num(y + 10) + "\" x2=\"" +
           Num(layout.legend_x + kSwatch) + "\" y2=\"" + Num(y + 10) + "\" stroke=\"" + color +
           "\" stroke-width=\"" + std::to_string(kMedianWidth) + "\"/>\n";
    svg += "<text class=\"legend-label\" x=\"" + Num(layout.legend_x + kSwatch + 8) + "\" y=\"" +
           Num(y + 10) + "\" dominant-baseline=\"middle\">" + Escape(series[k].label) + "</text>\n";
  }
  svg += "</g>\n</svg>\n";
  return svg;
}

io::RgbImage TuningPlotImage(const std::vector<TuningSeries>& series,
                             const TuningPlotOptions& options) {
  const Layout layout = MakeLayout(series, options);
  Canvas canvas(layout.width, layout.height, kBackground);
  const auto row = [](double y) { return static_cast<int64_t>(std::floor(y)); };

  for (const Tick& t : layout.y_ticks) {
    canvas.Line(layout.left, row(t.pixel), layout.right, row(t.pixel), 1, kGridLine);
  }
  for (size_t k = 0; k < series.size(); ++k) {
    canvas.FillPolygon(BandOutline(series[k], layout), TuningSeriesColor(k), kBandAlpha);
  }
  // The frame under the medians, so that a median on the edge stays whole.
  canvas.Line(layout.left, layout.top, layout.right, layout.top, 1, kInk);
  canvas.Line(layout.left, layout.bottom, layout.right, layout.bottom, 1, kInk);
  canvas.Line(layout.left, layout.top, layout.left, layout.bottom, 1, kInk);
  canvas.Line(layout.right, layout.top, layout.right, layout.bottom, 1, kInk);
  for (size_t k = 0; k < series.size(); ++k) {
    const std::vector<PixelPoint> median = MedianLine(series[k], layout);
    const Rgb color = TuningSeriesColor(k);
    if (median.size() == 1) {
      canvas.FillRect(PenCorner(median[0].x, 6), PenCorner(median[0].y, 6), 6, 6, color);
    }
    for (size_t i = 1; i < median.size(); ++i) {
      canvas.Line(PenCorner(median[i - 1].x, kMedianWidth),
                  PenCorner(median[i - 1].y, kMedianWidth), PenCorner(median[i].x, kMedianWidth),
                  PenCorner(median[i].y, kMedianWidth), kMedianWidth, color);
    }
  }

  // Ticks and text.
  for (const Tick& t : layout.y_ticks) {
    canvas.Line(layout.left - kTick, row(t.pixel), layout.left, row(t.pixel), 1, kInk);
    canvas.Text(layout.left - kTick - 4 - Canvas::TextWidth(t.text, kFontSize),
                static_cast<int>(row(t.pixel)) - kTextHeight / 2, t.text, kFontSize, kInk);
  }
  for (const Tick& t : layout.x_ticks) {
    canvas.Line(row(t.pixel), layout.bottom, row(t.pixel), layout.bottom + kTick, 1, kInk);
    canvas.Text(static_cast<int>(row(t.pixel)) - Canvas::TextWidth(t.text, kFontSize) / 2,
                layout.bottom + kTick + 6, t.text, kFontSize, kInk);
  }
  if (!options.title.empty()) {
    canvas.Text((layout.width - Canvas::TextWidth(options.title, kFontSize)) / 2, kPad,
                options.title, kFontSize, kInk);
  }
  if (!options.x_label.empty()) {
    canvas.Text((layout.left + layout.right - Canvas::TextWidth(options.x_label, kFontSize)) / 2,
                layout.height - kPad - kTextHeight, options.x_label, kFontSize, kInk);
  }
  if (!options.y_label.empty()) {
    canvas.TextUp(kPad,
                  (layout.top + layout.bottom + Canvas::TextWidth(options.y_label, kFontSize)) / 2,
                  options.y_label, kFontSize, kInk);
  }
  for (size_t k = 0; k < series.size(); ++k) {
    const int y = layout.top + static_cast<int>(k) * kLegendRow;
    const Rgb color = TuningSeriesColor(k);
    canvas.FillPolygon({{static_cast<double>(layout.legend_x), y + 4.0},
                        {static_cast<double>(layout.legend_x + kSwatch), y + 4.0},
                        {static_cast<double>(layout.legend_x + kSwatch), y + 16.0},
                        {static_cast<double>(layout.legend_x), y + 16.0}},
                       color, kBandAlpha);
    canvas.FillRect(layout.legend_x, y + 9, kSwatch, kMedianWidth, color);
    canvas.Text(layout.legend_x + kSwatch + 8, y + 10 - kTextHeight / 2, series[k].label, kFontSize,
                kInk);
  }
  return canvas.Take();
}

}  // namespace slam::offline
