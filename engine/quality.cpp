#include "engine/quality.hpp"

#include <algorithm>
#include <cmath>

namespace slam {

Vec2 RigidTransform2::Apply(const Vec2& p) const {
  const double c = std::cos(rotation_rad), s = std::sin(rotation_rad);
  return {c * p.x() - s * p.y() + translation.x(), s * p.x() + c * p.y() + translation.y()};
}

RigidTransform2 RigidTransform2::Inverse() const {
  const double c = std::cos(rotation_rad), s = std::sin(rotation_rad);
  const Vec2& t = translation;
  return {-rotation_rad, {-(c * t.x() + s * t.y()), -(-s * t.x() + c * t.y())}};
}

std::vector<TimedPose> TransformTrajectory(const RigidTransform2& transform,
                                           const std::vector<TimedPose>& trajectory) {
  std::vector<TimedPose> out;
  out.reserve(trajectory.size());
  for (const TimedPose& p : trajectory) {
    const Vec2 position = transform.Apply(p.pose.translation());
    out.push_back(
        {p.t, {position.x(), position.y(), NormalizeAngle(p.pose.theta + transform.rotation_rad)}});
  }
  return out;
}

RigidTransform2 AlignRigid2D(const std::vector<Vec2>& source, const std::vector<Vec2>& target) {
  const auto n = static_cast<double>(source.size());
  Vec2 mean_s = Vec2::Zero(), mean_t = Vec2::Zero();
  for (size_t i = 0; i < source.size(); ++i) {
    mean_s += source[i];
    mean_t += target[i];
  }
  mean_s /= n;
  mean_t /= n;
  // Closed-form 2D Procrustes: the angle maximising sum of <R s_i, t_i> over centred points.
  double dot = 0.0, cross = 0.0;
  for (size_t i = 0; i < source.size(); ++i) {
    const Vec2 a = source[i] - mean_s, b = target[i] - mean_t;
    dot += a.dot(b);
    cross += a.x() * b.y() - a.y() * b.x();
  }
  RigidTransform2 result;
  result.rotation_rad = std::atan2(cross, dot);
  result.translation = mean_t - RigidTransform2{result.rotation_rad, Vec2::Zero()}.Apply(mean_s);
  return result;
}

std::optional<Pose2> PoseAt(const std::vector<TimedPose>& trajectory, double t) {
  if (trajectory.empty() || t < trajectory.front().t || t > trajectory.back().t)
    return std::nullopt;
  const auto after = std::lower_bound(trajectory.begin(), trajectory.end(), t,
                                      [](const TimedPose& p, double time) { return p.t < time; });
  if (after->t == t || after == trajectory.begin()) return after->pose;
  const auto before = std::prev(after);
  const double span = after->t - before->t;
  return Interpolate(before->pose, after->pose, span > 0 ? (t - before->t) / span : 0.0);
}

namespace {

/// Each reference pose within the estimate's span, with the estimate at its time.
void Associate(const std::vector<TimedPose>& estimate, const std::vector<TimedPose>& reference,
               std::vector<Vec2>& source, std::vector<Vec2>& target) {
  for (const TimedPose& ref : reference) {
    if (const auto pose = PoseAt(estimate, ref.t)) {
      source.push_back(pose->translation());
      target.push_back(ref.pose.translation());
    }
  }
}

}  // namespace

std::optional<RigidTransform2> AlignOnMajority(const std::vector<TimedPose>& estimate,
                                               const std::vector<TimedPose>& reference,
                                               double floor_m) {
  std::vector<Vec2> source, target;
  Associate(estimate, reference, source, target);
  if (source.size() < 2) return std::nullopt;
  RigidTransform2 alignment = AlignRigid2D(source, target);
  std::vector<bool> kept(source.size(), true);
  std::vector<double> residuals(source.size());
  for (int round = 0; round < 20; ++round) {
    for (size_t i = 0; i < source.size(); ++i) {
      residuals[i] = (alignment.Apply(source[i]) - target[i]).norm();
    }
    std::vector<double> sorted = residuals;
    const auto middle = sorted.begin() + static_cast<std::ptrdiff_t>(sorted.size() / 2);
    std::nth_element(sorted.begin(), middle, sorted.end());
    const double bound = std::max(floor_m, 2.0 * *middle);
    std::vector<bool> within(source.size());
    std::vector<Vec2> s, t;
    for (size_t i = 0; i < source.size(); ++i) {
      within[i] = residuals[i] <= bound;
      if (within[i]) {
        s.push_back(source[i]);
        t.push_back(target[i]);
      }
    }
    // At least half the poses are within twice the median; two are needed for a fit.
    if (within == kept || s.size() < 2) break;
    kept = std::move(within);
    alignment = AlignRigid2D(s, t);
  }
  return alignment;
}

std::optional<TrajectoryQuality> EvaluateTrajectory(const std::vector<TimedPose>& estimate,
                                                    const std::vector<TimedPose>& reference) {
  std::vector<Vec2> source, target;
  Associate(estimate, reference, source, target);
  if (source.size() < 2) return std::nullopt;
  TrajectoryQuality quality;
  quality.alignment = AlignRigid2D(source, target);
  double sum_sq = 0.0;
  for (size_t i = 0; i < source.size(); ++i) {
    sum_sq += (quality.alignment.Apply(source[i]) - target[i]).squaredNorm();
  }
  const double mean_sq_m2 = sum_sq / static_cast<double>(source.size());
  quality.matched = static_cast<int>(source.size());
  quality.q_cm2 = -mean_sq_m2 * 1e4;          // eq. 8 with positions in centimetres
  quality.e = std::log(1.0 - quality.q_cm2);  // eq. 9
  quality.ate_rmse_m = std::sqrt(mean_sq_m2);
  return quality;
}

double ErrorLowerBound(const std::vector<TimedPose>& prefix,
                       const std::vector<TimedPose>& reference) {
  if (prefix.empty()) return 0.0;
  const std::optional<TrajectoryQuality> quality = EvaluateTrajectory(prefix, reference);
  if (!quality) return 0.0;
  const double start = prefix.front().t;
  const auto reachable = std::count_if(reference.begin(), reference.end(),
                                       [&](const TimedPose& r) { return r.t >= start; });
  if (reachable == 0) return 0.0;
  // The prefix's aligned sum of squares (cm^2), spread over every pose the whole run can match.
  const double sum_sq_cm2 = -quality->q_cm2 * static_cast<double>(quality->matched);
  return std::log1p(sum_sq_cm2 / static_cast<double>(reachable));
}

}  // namespace slam
