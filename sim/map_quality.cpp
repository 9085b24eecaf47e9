#include "sim/map_quality.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>
#include <utility>

#include "engine/cell_encoding.hpp"
#include "engine/grid_geometry.hpp"

namespace slam::sim {
namespace {

// A ray toward a sample that stops this much short of it was blocked by something else; the
// slack absorbs rounding at tangent rays and wall ends.
constexpr double kLineOfSightSlackM = 0.01;

/// Distance from p to the segment [a, b].
double PointSegmentDistance(const Vec2& p, const Vec2& a, const Vec2& b) {
  const Vec2 e = b - a;
  const double len2 = e.squaredNorm();
  const double s = len2 > 0.0 ? std::clamp((p - a).dot(e) / len2, 0.0, 1.0) : 0.0;
  return (a + s * e - p).norm();
}

/// Distance from p to the nearest wall or circle boundary (inside a circle too); +inf if none.
double SurfaceDistance(const World& world, const Vec2& p) {
  double best = std::numeric_limits<double>::infinity();
  for (const Segment& seg : world.segments) {
    best = std::min(best, PointSegmentDistance(p, seg.a, seg.b));
  }
  for (const Circle& circle : world.circles) {
    best = std::min(best, std::abs((p - circle.center).norm() - circle.radius_m));
  }
  return best;
}

/// Number of equal intervals of at most `step` covering `length` (at least one).
int64_t IntervalCount(double length, double step) {
  // The small margin keeps 1.0 / 0.01 at 100 intervals despite rounding.
  return std::max<int64_t>(1, static_cast<int64_t>(std::ceil(length / step - 1e-9)));
}

/// Samples of every surface: the midpoints of equal intervals of at most `step` along each
/// segment and each circle boundary (so corners shared by two walls are not sampled twice).
std::vector<Vec2> SurfaceSamples(const World& world, double step) {
  std::vector<Vec2> samples;
  for (const Segment& seg : world.segments) {
    const int64_t n = IntervalCount((seg.b - seg.a).norm(), step);
    for (int64_t i = 0; i < n; ++i) {
      const double s = (static_cast<double>(i) + 0.5) / static_cast<double>(n);
      samples.push_back(seg.a + s * (seg.b - seg.a));
    }
  }
  for (const Circle& circle : world.circles) {
    const int64_t n = IntervalCount(2.0 * kPi * circle.radius_m, step);
    for (int64_t i = 0; i < n; ++i) {
      const double a = 2.0 * kPi * (static_cast<double>(i) + 0.5) / static_cast<double>(n);
      samples.push_back(circle.center + circle.radius_m * Vec2(std::cos(a), std::sin(a)));
    }
  }
  return samples;
}

/// Positions of the poses kept: the first, then each at least `step_s` after the last kept.
std::vector<Vec2> KeptPositions(const std::vector<TimedPose>& trajectory, double step_s) {
  std::vector<Vec2> positions;
  double last_t = 0.0;
  for (const TimedPose& p : trajectory) {
    if (!positions.empty() && p.t - last_t < step_s) continue;
    positions.push_back(p.pose.translation());
    last_t = p.t;
  }
  return positions;
}

/// True when some position sees `sample` within `range` with nothing in between.
bool Observable(const World& world, const std::vector<Vec2>& positions, const Vec2& sample,
                double range) {
  for (const Vec2& origin : positions) {
    const Vec2 d = sample - origin;
    const double dist2 = d.squaredNorm();
    if (dist2 > range * range) continue;
    const double dist = std::sqrt(dist2);
    if (dist <= kLineOfSightSlackM) return true;
    const auto hit =
        RayDistance(world, origin, std::atan2(d.y(), d.x()), dist + kLineOfSightSlackM);
    if (!hit || *hit >= dist - kLineOfSightSlackM) return true;
  }
  return false;
}

/// Points in square buckets of side `bucket`, sorted by bucket: answers "is any point within
/// `bucket` of q?" by looking at the 3 x 3 buckets around q.
class PointHash {
 public:
  PointHash(const std::vector<Vec2>& points, double bucket) : inv_(1.0 / bucket), bucket_(bucket) {
    entries_.reserve(points.size());
    for (const Vec2& p : points) entries_.push_back({KeyOf(p), p});
    std::sort(entries_.begin(), entries_.end(),
              [](const Entry& a, const Entry& b) { return a.key < b.key; });
  }

  bool AnyWithin(const Vec2& q) const {
    const Key center = KeyOf(q);
    for (int64_t dy = -1; dy <= 1; ++dy) {
      for (int64_t dx = -1; dx <= 1; ++dx) {
        const Key key{center.first + dx, center.second + dy};
        auto it = std::lower_bound(entries_.begin(), entries_.end(), key,
                                   [](const Entry& e, const Key& k) { return e.key < k; });
        for (; it != entries_.end() && it->key == key; ++it) {
          if ((it->point - q).squaredNorm() <= bucket_ * bucket_) return true;
        }
      }
    }
    return false;
  }

 private:
  using Key = std::pair<int64_t, int64_t>;
  struct Entry {
    Key key;
    Vec2 point;
  };

  Key KeyOf(const Vec2& p) const {
    return {static_cast<int64_t>(std::floor(p.x() * inv_)),
            static_cast<int64_t>(std::floor(p.y() * inv_))};
  }

  double inv_;
  double bucket_;
  std::vector<Entry> entries_;
};

/// World positions of the centres of the map's cells with p >= occupied_probability.
std::vector<Vec2> OccupiedCentres(const OccupancyGrid& map, const RigidTransform2& map_to_world,
                                  double occupied_probability) {
  std::vector<Vec2> centres;
  const GridGeometry& geometry = map.geometry();
  for (const TileRef& t : map.Tiles()) {
    const CellIndex origin = GridGeometry::TileOrigin(t.index);
    for (int j = 0; j < kTileSize; ++j) {
      for (int i = 0; i < kTileSize; ++i) {
        const LogOdds v = t.tile->cells[static_cast<size_t>(j * kTileSize + i)];
        if (v <= 0 || OccupancyProbability(v) < occupied_probability) continue;
        centres.push_back(map_to_world.Apply(geometry.CellCenter({origin.x + i, origin.y + j})));
      }
    }
  }
  return centres;
}

double Ratio(int64_t num, int64_t den) {
  return den > 0 ? static_cast<double>(num) / static_cast<double>(den) : 0.0;
}

}  // namespace

ConfigErrors MapQualityConfig::Validate() const {
  ConfigErrors errors;
  auto check = [&](bool ok, const char* pointer, const char* detail) {
    if (!ok) errors.push_back({pointer, detail});
  };
  // Written so that NaN fails too.
  check(tolerance_m >= 0.001 && tolerance_m <= 1.0, "/tolerance_m", "must be in [0.001, 1] m");
  check(occupied_probability > 0.5 && occupied_probability < 1.0, "/occupied_probability",
        "must be in (0.5, 1)");
  check(visible_range_m > 0.0 && visible_range_m <= 100.0, "/visible_range_m",
        "must be in (0, 100] m");
  check(surface_step_m >= 0.001 && surface_step_m <= 1.0, "/surface_step_m",
        "must be in [0.001, 1] m");
  check(pose_step_s >= 0.0 && pose_step_s <= 3600.0, "/pose_step_s", "must be in [0, 3600] s");
  return errors;
}

MapQuality EvaluateMap(const OccupancyGrid& map, const RigidTransform2& map_to_world,
                       const World& world, const std::vector<TimedPose>& ground_truth,
                       const MapQualityConfig& config) {
  MapQuality q;
  q.tolerance_m = config.tolerance_m;
  if (!config.Validate().empty()) return q;

  // Precision: every occupied cell against the nearest surface.
  const std::vector<Vec2> occupied =
      OccupiedCentres(map, map_to_world, config.occupied_probability);
  q.occupied_cells = static_cast<int64_t>(occupied.size());
  for (const Vec2& p : occupied) {
    if (SurfaceDistance(world, p) <= config.tolerance_m) ++q.true_occupied_cells;
  }
  q.precision = Ratio(q.true_occupied_cells, q.occupied_cells);

  // Recall: every observable surface sample against the nearest occupied cell.
  const PointHash occupied_hash(occupied, config.tolerance_m);
  const std::vector<Vec2> positions = KeptPositions(ground_truth, config.pose_step_s);
  for (const Vec2& sample : SurfaceSamples(world, config.surface_step_m)) {
    if (!Observable(world, positions, sample, config.visible_range_m)) continue;
    ++q.surface_points;
    if (occupied_hash.AnyWithin(sample)) ++q.surface_points_found;
  }
  q.recall = Ratio(q.surface_points_found, q.surface_points);

  const double sum = q.precision + q.recall;
  q.f1 = sum > 0.0 ? 2.0 * q.precision * q.recall / sum : 0.0;
  return q;
}

}  // namespace slam::sim
