#pragma once
// The Fig. 10-like plot of a tuning run: for each ray budget, the median fitness and the
// interquartile band of the evolution strategy's population at every generation (x = generation,
// y = fitness e, lower is better), as SVG text or as a raster image for PNG.

#include <array>
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "engine/io/map_image.hpp"

namespace slam::offline {

/// The population's fitness at one generation: first quartile, median, third quartile.
struct TuningBand {
  double q1 = 0.0;
  double median = 0.0;
  double q3 = 0.0;
};

/// One ray budget: its legend text and its generations in order (none for a run not started);
/// the plot numbers them from 1, as slam-tune does.
struct TuningSeries {
  std::string label;
  std::vector<TuningBand> generations;
};

struct TuningPlotOptions {
  std::string title = "Fitness per generation";
  std::string x_label = "generation";
  std::string y_label = "fitness e = log(1 - q)";
  int width = 900;   // pixels, clamped to [240, 8192]
  int height = 560;  // pixels, clamped to [180, 8192]
};

/// The colour of series `index` (Okabe-Ito, colour-blind friendly; repeats after 8 series).
std::array<uint8_t, 3> TuningSeriesColor(size_t index);

/// SVG text of the plot: axes with "nice" ticks (1, 2, 5 x 10^k for fitness, integers for
/// generations) and labels, per series with a finite value a translucent interquartile band and
/// a median polyline (non-finite values skipped; a lone point also gets a marker), a legend
/// naming every series. Text is XML-escaped.
std::string TuningPlotSvg(const std::vector<TuningSeries>& series,
                          const TuningPlotOptions& options = {});

/// The same plot with the same layout, rasterised with io::Canvas (text in its 5x7 font, upper
/// case), for io::EncodePng / io::WritePng.
io::RgbImage TuningPlotImage(const std::vector<TuningSeries>& series,
                             const TuningPlotOptions& options = {});

}  // namespace slam::offline
