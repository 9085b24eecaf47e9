#include "engine/scan_matcher.hpp"

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <limits>

#include "engine/for_each.hpp"
#include "engine/match_window.hpp"
#include "engine/matching_rays.hpp"
#include "engine/random.hpp"

namespace slam {
namespace {

// Random stream of candidate c of a particle (kinds 0 and 1 are the motion's and the
// resampling's, Slam's).
constexpr uint64_t kStreamCandidate = 2;  // + candidate index

// Rounds of the search after its first, around the best candidate so far.
constexpr size_t kClimbRounds = 4;

// The fitted peak may lie at most this many search spreads from the best candidate (farther,
// the quadratic is extrapolated: the best candidate stays).
constexpr double kPeakFitMaxStep = 2.0;
// Candidates whose log-likelihood lies more than this many units per matched reading below the
// best one's are left out of the fit: they sit on the likelihood's floor, and where the peak is
// sharp (a map that fits the readings well) a quadratic through them misplaces it. Chosen among
// 1, 1.5, 2 and none on the validation worlds (docs/accuracy.md).
constexpr double kPeakFitWindowPerReading = 1.5;

// The largest MatchWindow a particle gets (4 bytes a cell: 16 MiB), whatever its rays: more
// means rays far longer than the scanner's, or very fine cells, cast through the map instead.
// Below it a window holds at most 4 x 16 bytes per ray its particle casts.
constexpr int64_t kMaxMatchWindowCells = int64_t{1} << 22;
// A window pays for itself when its particle's candidates cast at least one ray per this many
// of its cells (what a window costs per cell and saves per ray: BM_MatchWindowBuild and
// BM_MatchingRayWindow, bench/).
constexpr int64_t kCellsPerRayPaid = 16;
// A window reaches this many heading spreads of the candidates around each ray's end.
constexpr double kWindowTurnSigmas = 2.0;

constexpr double Square(double x) { return x * x; }

}  // namespace

double ScanMatcher::LogLikelihood(const OccupancyGrid& map, const MatchWindow* window,
                                  const ScanPath& path, const Pose2& correction,
                                  std::span<const Measurement* const> matching) const {
  // The candidate's rays, cast as one batch (several in flight); buffers reused per thread.
  thread_local std::vector<RayQuery> rays;
  thread_local std::vector<RayHit> hits;
  rays.clear();
  size_t sample = SIZE_MAX;
  ScanPath::Frame frame{};
  for (const Measurement* m : matching) {
    if (m->sample != sample) {  // the sensors of one sample share its pose
      sample = m->sample;
      frame = path.SampleFrame(sample, correction);
    }
    rays.push_back(
        {frame.Point(m->local_origin), frame.Direction(m->local_direction), m->match_range_m});
  }
  if (window != nullptr) {
    CastToObstacles(*window, rays, hits);
  } else {
    CastToObstacles(map, rays, config_.occupied_above, hits);
  }
  // The sum of log(g + floor), as the log of products of its terms (each in [floor, 1 + floor)),
  // taken whenever a product nears the ends of the double range: one log for many rays instead
  // of one each.
  double ll = 0.0, product = 1.0;
  for (size_t i = 0; i < matching.size(); ++i) {
    const Measurement& m = *matching[i];
    const RayHit& hit = hits[i];
    double g = 0.0;
    if (hit.hit) {
      // The surface lies somewhere along the ray's crossing of the first occupied cell, which is
      // longer than a cell for oblique walls: expect it in the middle of the crossing.
      const double r = (m.distance_m - 0.5 * (hit.distance_m + hit.exit_m)) / m.sigma_m;
      g = std::exp(-0.5 * r * r);
    }
    product *= g + config_.match_floor;
    if (!(product > 1e-150 && product < 1e150)) {
      ll += std::log(product);
      product = 1.0;
    }
  }
  return ll + std::log(product);
}

MatchResult ScanMatcher::Match(std::span<const MatchRequest> requests,
                               std::span<const Measurement* const> matching,
                               const MatchSearch& search, uint64_t step,
                               const std::atomic<bool>* interrupt) const {
  const size_t n_particles = requests.size();
  const size_t n_candidates = std::max<size_t>(1, search.candidates);
  MatchResult out;
  out.chosen.resize(n_particles);
  out.chosen_ll.assign(n_particles, 0.0);
  const double sigma_pos = search.search.pos;
  const double sigma_angle = search.search.angle;
  // The first half of the candidates explore: wide enough to re-acquire a pose that drifted. The
  // rest climb in up to kClimbRounds rounds to settle close to the likelihood's peak. Rounds run
  // one after the other; the candidates of a round run in parallel, each from its own random
  // stream, so serial equals parallel.
  const size_t explore = std::max<size_t>(1, (n_candidates + 1) / 2);
  const size_t round_size =
      std::max<size_t>(1, (n_candidates - explore + kClimbRounds - 1) / kClimbRounds);
  std::vector<Pose2> candidate_pose(n_particles * n_candidates);
  std::vector<double> candidate_ll(n_particles * n_candidates);
  std::vector<size_t> best(n_particles);  // per particle: index of its best candidate so far
  for (size_t p = 0; p < n_particles; ++p) best[p] = p * n_candidates;
  std::atomic<size_t> skipped{0};
  // Each candidate's score is its log-likelihood plus its log-prior under the motion model
  // around the odometry's end pose: where the readings tell the candidates little apart, the
  // odometry wins rather than the luckiest candidate (the maximum of many noisy likelihoods).
  std::vector<double> candidate_score(n_particles * n_candidates);
  const auto log_prior = [&](size_t p, const Pose2& c) {
    const Pose2& nominal = requests[p].nominal;
    return -0.5 * (Square(c.x - nominal.x) + Square(c.y - nominal.y)) / Square(search.prior.pos) -
           0.5 * Square(NormalizeAngle(c.theta - nominal.theta)) / Square(search.prior.angle);
  };
  // The heading sweep: the first explore candidates after the prediction, evenly over +- sweep,
  // at most half of them, an odd number (symmetric around the prediction).
  size_t sweep_count = 0;
  if (search.sweep > 0 && explore >= 5) {
    const auto wanted =
        static_cast<size_t>(2 * std::floor(search.sweep / config_.sweep_step_rad) + 1);
    sweep_count = std::min(wanted, (explore - 1) / 2);
    if (sweep_count % 2 == 0) --sweep_count;
  }
  size_t first = 0;
  for (int round = 0; first < n_candidates; ++round) {
    const size_t last = std::min(n_candidates, round == 0 ? explore : first + round_size);
    const size_t width = last - first;
    const double scale = std::ldexp(1.0, -round);  // 1, 1/2, 1/4, ...
    std::vector<Pose2> centre(n_particles);
    for (size_t p = 0; p < n_particles; ++p) {
      centre[p] = round == 0 ? requests[p].predicted : candidate_pose[best[p]];
    }
    ForEach(config_.parallel, n_particles * width, [&](size_t k) {
      const size_t p = k / width, c = first + k % width;
      const size_t index = p * n_candidates + c;
      const MatchRequest& request = requests[p];
      if (c > 0 && interrupt != nullptr && interrupt->load(std::memory_order_relaxed)) {
        candidate_pose[index] = request.predicted;
        candidate_ll[index] = -std::numeric_limits<double>::infinity();  // never chosen
        candidate_score[index] = candidate_ll[index];
        skipped.fetch_add(1, std::memory_order_relaxed);
        return;
      }
      Pose2 end = centre[p];
      if (round == 0 && c >= 1 && c <= sweep_count) {
        const double offset = sweep_count == 1
                                  ? 0.0
                                  : search.sweep * (2.0 * static_cast<double>(c - 1) /
                                                        static_cast<double>(sweep_count - 1) -
                                                    1.0);
        end.theta = NormalizeAngle(end.theta + offset);
      } else if (c > 0) {
        Rng rng = Rng::ForStream(config_.seed, step, p, kStreamCandidate + c);
        end.x += rng.Normal(scale * sigma_pos);
        end.y += rng.Normal(scale * sigma_pos);
        end.theta = NormalizeAngle(end.theta + rng.Normal(scale * sigma_angle));
      }
      candidate_pose[index] = end;
      candidate_ll[index] = LogLikelihood(*request.map, request.window, *request.path,
                                          request.path->CorrectionTo(end), matching);
      candidate_score[index] = candidate_ll[index] + log_prior(p, end);
    });
    for (size_t p = 0; p < n_particles; ++p) {
      for (size_t c = first; c < last; ++c) {
        const size_t i = p * n_candidates + c;
        if (candidate_score[i] > candidate_score[best[p]]) best[p] = i;
      }
    }
    first = last;
  }
  double ambiguity = 0.0;
  for (size_t p = 0; p < n_particles; ++p) {
    out.chosen[p] = candidate_pose[best[p]];
    // The particle's weight takes the best candidate's log-likelihood, wherever the fit moves it.
    out.chosen_ll[p] = candidate_ll[best[p]];
    if (config_.fit_peak && n_candidates >= static_cast<size_t>(kPeakFitMinCandidates)) {
      const size_t begin = p * n_candidates;
      const std::optional<Pose2> peak = FittedPeak(
          std::span(candidate_pose).subspan(begin, n_candidates),
          std::span(candidate_ll).subspan(begin, n_candidates), matching.size(),
          candidate_pose[best[p]], requests[p].nominal, {sigma_pos, sigma_angle}, search.prior);
      if (peak) out.chosen[p] = *peak;
    }
    if (explore > 1) {
      // The first round's posterior (weights exp(ll - its best ll)) around its winner: how
      // little the measurements told the candidates drawn from the proposal apart.
      size_t winner = p * n_candidates;
      for (size_t c = 1; c < explore; ++c) {
        if (candidate_ll[p * n_candidates + c] > candidate_ll[winner])
          winner = p * n_candidates + c;
      }
      double weight_sum = 0.0, spread_sq = 0.0;
      for (size_t c = 0; c < explore; ++c) {
        const size_t i = p * n_candidates + c;
        const double w = std::exp(candidate_ll[i] - candidate_ll[winner]);
        const double dx = candidate_pose[i].x - candidate_pose[winner].x,
                     dy = candidate_pose[i].y - candidate_pose[winner].y;
        weight_sum += w;
        spread_sq += w * (dx * dx + dy * dy);
      }
      ambiguity += std::sqrt(spread_sq / weight_sum) / std::max(std::sqrt(2.0) * sigma_pos, 1e-9);
    }
  }
  out.ambiguity = ambiguity / static_cast<double>(n_particles);
  out.rays = static_cast<int64_t>((n_particles * n_candidates - skipped.load()) * matching.size());
  out.interrupted = skipped.load() > 0;
  return out;
}

std::optional<Pose2> FittedPeak(std::span<const Pose2> poses, std::span<const double> ll,
                                size_t readings, const Pose2& best, const Pose2& nominal,
                                Spread search, Spread prior) {
  const double top = *std::max_element(ll.begin(), ll.end());
  const double lowest = top - kPeakFitWindowPerReading * static_cast<double>(readings);
  using Vector10 = Eigen::Matrix<double, 10, 1>;
  Eigen::Matrix<double, 10, 10> normal = Eigen::Matrix<double, 10, 10>::Zero();
  Vector10 rhs = Vector10::Zero();
  size_t used = 0;
  for (size_t i = 0; i < poses.size(); ++i) {
    if (!std::isfinite(ll[i]) || ll[i] < lowest) continue;  // interrupted, or on the floor
    const double u = (poses[i].x - best.x) / search.pos, v = (poses[i].y - best.y) / search.pos,
                 t = NormalizeAngle(poses[i].theta - best.theta) / search.angle;
    const double w = std::exp(-0.5 * (u * u + v * v + t * t));
    Vector10 f;
    f << 1, u, v, t, u * u, v * v, t * t, u * v, u * t, v * t;
    normal.selfadjointView<Eigen::Lower>().rankUpdate(f, w);
    rhs += w * ll[i] * f;
    ++used;
  }
  if (used < kPeakFitMinCandidates) return std::nullopt;
  const Vector10 a = normal.selfadjointView<Eigen::Lower>().ldlt().solve(rhs);
  if (!a.allFinite()) return std::nullopt;
  Eigen::Matrix3d curvature;
  curvature << 2 * a[4], a[7], a[8], a[7], 2 * a[5], a[9], a[8], a[9], 2 * a[6];
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eigen(curvature);
  const Eigen::Matrix3d falling = eigen.eigenvectors() *
                                  eigen.eigenvalues().cwiseMin(0.0).asDiagonal() *
                                  eigen.eigenvectors().transpose();
  // Maximise a + g.x + x'Hx/2 - (x - n)'P(x - n)/2: (P - H) x = g + P n.
  const Eigen::Vector3d precision(Square(search.pos / prior.pos), Square(search.pos / prior.pos),
                                  Square(search.angle / prior.angle));
  const Eigen::Vector3d centre((nominal.x - best.x) / search.pos, (nominal.y - best.y) / search.pos,
                               NormalizeAngle(nominal.theta - best.theta) / search.angle);
  const Eigen::Matrix3d lhs = Eigen::Matrix3d(precision.asDiagonal()) - falling;
  // The fitted slope along each principal direction counts in proportion to that direction's
  // share of the information (its curvature against the prior's precision there): along a
  // direction the readings hardly tell apart, the slope is the fit's noise.
  Eigen::Vector3d along = eigen.eigenvectors().transpose() * a.segment<3>(1);
  for (int k = 0; k < 3; ++k) {
    const Eigen::Vector3d v = eigen.eigenvectors().col(k);
    const double information = std::max(0.0, -eigen.eigenvalues()[k]);
    along[k] *= information / (information + v.cwiseProduct(v).dot(precision));
  }
  const Eigen::Vector3d gradient = eigen.eigenvectors() * along;
  const Eigen::Vector3d step = lhs.ldlt().solve(gradient + precision.cwiseProduct(centre));
  if (!step.allFinite() || step.norm() > kPeakFitMaxStep) return std::nullopt;
  return Pose2{best.x + step[0] * search.pos, best.y + step[1] * search.pos,
               NormalizeAngle(best.theta + step[2] * search.angle)};
}

std::optional<WindowBounds> PlanWindow(const GridGeometry& geometry, const ScanPath& path,
                                       const Pose2& predicted,
                                       std::span<const Measurement* const> matching,
                                       const MatchSearch& search) {
  // The rays' own ends rather than the longest ray all around: near a wall, the window stops a
  // little beyond it instead of a ray's length beyond. Candidates drawn beyond 4 position
  // spreads cast through the map.
  const Pose2 correction = path.CorrectionTo(predicted);
  std::array<double, 4> box = path.Extent(correction);
  for (const Measurement* m : matching) {
    const ScanPath::Frame frame = path.SampleFrame(m->sample, correction);
    const Vec2 origin = frame.Point(m->local_origin);
    const Vec2 end = frame.Point(m->local_origin + m->local_direction * m->match_range_m);
    const double turn = std::max(kWindowTurnSigmas * search.search.angle, search.sweep) *
                        (m->local_origin.norm() + m->match_range_m);
    box = {std::min({box[0], origin.x(), end.x() - turn}),
           std::min({box[1], origin.y(), end.y() - turn}),
           std::max({box[2], origin.x(), end.x() + turn}),
           std::max({box[3], origin.y(), end.y() + turn})};
  }
  const double pad = 4.0 * search.search.pos + 3.0 * geometry.resolution();
  // Near the map's bound (or beyond it), no window: the rays go through the grid, which clips
  // them to the bound.
  if (!geometry.InMapBound({box[0] - pad, box[1] - pad}) ||
      !geometry.InMapBound({box[2] + pad, box[3] + pad})) {
    return std::nullopt;
  }
  const CellIndex lo = geometry.CellOf({box[0] - pad, box[1] - pad});
  const CellIndex hi = geometry.CellOf({box[2] + pad, box[3] + pad});
  const int64_t cells = (int64_t{hi.x} - lo.x + 1) * (int64_t{hi.y} - lo.y + 1);
  const auto rays = static_cast<int64_t>(std::max<size_t>(1, search.candidates) * matching.size());
  if (cells <= kMaxMatchWindowCells && rays * kCellsPerRayPaid >= cells)
    return WindowBounds{lo, hi};
  return std::nullopt;
}

}  // namespace slam
