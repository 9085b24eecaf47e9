#pragma once
// The filter's particles (paper section V-D): each a pose, a weight, its own map and its history,
// sharing maps' tiles and histories' chunks with the particles it was copied from.

#include <cstddef>
#include <memory>
#include <vector>

#include "engine/occupancy_grid.hpp"
#include "engine/pose.hpp"
#include "engine/random.hpp"

namespace slam {

/// History of a particle: one chunk per scan, shared with the ancestors it was copied from.
struct TrajectoryChunk {
  std::vector<TimedPose> poses;  // the scan's sample poses and its end pose, time-ordered
  mutable std::shared_ptr<const TrajectoryChunk> parent;  // mutable: unlinked on destruction
  ~TrajectoryChunk();  // iterative, so that long histories do not overflow the stack
};

struct Particle {
  Pose2 pose;
  double log_weight = 0.0;
  OccupancyGrid map;
  std::shared_ptr<const TrajectoryChunk> history;
  // The heading drift of the odometry as this particle's matches have measured it
  // (counter-clockwise positive); its prediction takes it out. Where the heading comes from a
  // gyro it is the gyro's bias, per second; where it comes from the encoders, the wheels'
  // systematic error, per metre driven (RobotDescription's base.heading_from_gyro).
  double heading_drift = 0.0;
};

/// A particle's history as one time-ordered trajectory.
std::vector<TimedPose> History(const Particle& particle);

/// Particle weights normalised to sum to 1 (from log weights, without overflow).
std::vector<double> NormalizedWeights(const std::vector<Particle>& particles);

/// The index of the particle with the largest weight (the lowest on ties).
size_t BestIndex(const std::vector<Particle>& particles);

/// 1 / sum of the squared normalised weights: how many particles the weights are worth.
double EffectiveSampleSize(const std::vector<Particle>& particles);

/// Draws `wanted` particles in proportion to their weights (low-variance resampling over the
/// particles sorted by weight, one uniform draw from `rng`); the drawn particles share maps and
/// histories with their parents, and their weights restart at 0.
void Resample(std::vector<Particle>& particles, size_t wanted, Rng& rng);

}  // namespace slam
