#pragma once
// Phase B: the pose refinement (paper section V-B). For each particle, candidate end poses of
// the scan are drawn around its predicted pose, each scored by the likelihood of the scan's
// matching readings on the particle's map (eq. 2, ray-cast) plus the motion prior, and the peak
// of the log-likelihood is fitted over them. Pure: it reads maps and writes nothing but its
// result; serial and parallel runs give the same answer.

#include <atomic>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <span>
#include <vector>

#include "engine/grid_geometry.hpp"
#include "engine/occupancy_grid.hpp"
#include "engine/pose.hpp"
#include "engine/scan_path.hpp"

namespace slam {

class MatchWindow;

/// The peak fit (FittedPeak) needs at least this many candidates; a particle with fewer keeps
/// its best candidate.
inline constexpr int kPeakFitMinCandidates = 20;

/// A search or prior spread: position (m) and heading (rad) standard deviations.
struct Spread {
  double pos = 0.0, angle = 0.0;
};

/// The matcher's settings (from SlamConfig).
struct MatcherConfig {
  LogOdds occupied_above = 0;   // matching rays stop at cells above this
  double match_floor = 0.05;    // robust likelihood floor of one reading (SlamConfig)
  bool fit_peak = true;         // fit the log-likelihood's peak (false: the best candidate)
  double sweep_step_rad = 0.0;  // heading sweep's step (SlamConfig::heading_sweep_step_deg)
  uint64_t seed = 1;            // of the candidates' random streams
  bool parallel = true;         // oneTBB across particles and candidates
};

/// One particle's matching problem: its map (cast through `window` when not null), its path
/// through the scan, the pose its motion predicts (the first candidate, centre of the first
/// round) and the odometry's end pose (the motion prior's centre).
struct MatchRequest {
  const OccupancyGrid* map = nullptr;
  const MatchWindow* window = nullptr;
  const ScanPath* path = nullptr;
  Pose2 predicted;
  Pose2 nominal;
};

/// How the candidates are spread, the same for every particle of a scan.
struct MatchSearch {
  size_t candidates = 1;  // per particle, the prediction included
  Spread search;          // of the first round's draws around the prediction
  Spread prior;           // of the motion prior around the nominal pose
  double sweep = 0.0;     // half the heading sweep's width (rad), 0 without one
};

struct MatchResult {
  std::vector<Pose2> chosen;      // per particle: the fitted peak, or its best candidate
  std::vector<double> chosen_ll;  // per particle: the best candidate's log-likelihood
  int64_t rays = 0;               // matching rays cast
  double ambiguity = 0.0;         // ScanReport::refinement_ambiguity
  bool interrupted = false;       // candidates skipped on the interrupt flag
};

/// The cells of a particle's MatchWindow (inclusive).
struct WindowBounds {
  CellIndex lo, hi;
};

class ScanMatcher {
 public:
  explicit ScanMatcher(const MatcherConfig& config) : config_(config) {}

  /// Eq. (2), robust to outliers, of the readings `matching` placed along `path` under
  /// `correction`: the sum over readings of log(g + floor), g the Gaussian of the difference
  /// between the measured distance and the middle of the ray's crossing of the first occupied
  /// cell (0 when the ray hits nothing within its range). Rays cast through `window` when not
  /// null, else through `map`.
  double LogLikelihood(const OccupancyGrid& map, const MatchWindow* window, const ScanPath& path,
                       const Pose2& correction, std::span<const Measurement* const> matching) const;

  /// The search for every request of a scan (`step` selects the candidates' random streams,
  /// the request's index the particle's). The first half of each particle's candidates are
  /// drawn around its prediction (candidate 0 is the prediction itself; with a sweep, the first
  /// ones are headings spread evenly over +- sweep), the rest in up to four rounds around the
  /// best so far, the spread halving each round. Each candidate's score is its log-likelihood
  /// plus its log-prior; the best score wins, and the peak fit may move it. While `interrupt`
  /// (may be null) is set, candidates beyond each particle's first are skipped.
  MatchResult Match(std::span<const MatchRequest> requests,
                    std::span<const Measurement* const> matching, const MatchSearch& search,
                    uint64_t step, const std::atomic<bool>* interrupt = nullptr) const;

  const MatcherConfig& config() const { return config_; }

 private:
  MatcherConfig config_;
};

/// The pose maximising a quadratic fitted to the candidates' log-likelihoods `ll` at `poses`
/// plus the motion prior (a Gaussian of spread `prior` around `nominal`). The quadratic is fitted
/// by least squares in units of the search spread, weighted by a Gaussian of that spread around
/// `best`, over the candidates within a window (per matched reading, `readings` of them) below
/// the best log-likelihood. Its curvature is clamped to at most zero, and its slope along each
/// principal direction shrunk by that direction's share of the information: where the
/// likelihood does not fall off (along a corridor's walls), the prior decides. Empty when fewer
/// than kPeakFitMinCandidates take part, the fit is ill-posed, or its peak lies farther than two
/// spreads from `best` (docs/accuracy.md, "The likelihood's peak").
std::optional<Pose2> FittedPeak(std::span<const Pose2> poses, std::span<const double> ll,
                                size_t readings, const Pose2& best, const Pose2& nominal,
                                Spread search, Spread prior);

/// The cells a particle's candidates can reach, worth a MatchWindow, or none: each matching ray
/// from its sample's pose under the predicted correction, its end widened by two heading
/// spreads (or the sweep) over the ray's reach, all of it padded by 4 position spreads and 3
/// cells. None near the map's bound, above the largest window (2^22 cells), or where the
/// candidates' rays are too few to pay for its cells (one cell per 16 rays).
std::optional<WindowBounds> PlanWindow(const GridGeometry& geometry, const ScanPath& path,
                                       const Pose2& predicted,
                                       std::span<const Measurement* const> matching,
                                       const MatchSearch& search);

}  // namespace slam
