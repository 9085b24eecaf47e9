#include "engine/particle_set.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <utility>

namespace slam {

TrajectoryChunk::~TrajectoryChunk() {
  std::shared_ptr<const TrajectoryChunk> next = std::move(parent);
  while (next && next.use_count() == 1) {
    std::shared_ptr<const TrajectoryChunk> grand = std::move(next->parent);
    next = std::move(grand);
  }
}

std::vector<TimedPose> History(const Particle& particle) {
  std::vector<const TrajectoryChunk*> chunks;
  for (const TrajectoryChunk* c = particle.history.get(); c != nullptr; c = c->parent.get()) {
    chunks.push_back(c);
  }
  std::vector<TimedPose> poses;
  for (auto it = chunks.rbegin(); it != chunks.rend(); ++it) {
    poses.insert(poses.end(), (*it)->poses.begin(), (*it)->poses.end());
  }
  return poses;
}

std::vector<double> NormalizedWeights(const std::vector<Particle>& particles) {
  double max_lw = -std::numeric_limits<double>::infinity();
  for (const Particle& p : particles) max_lw = std::max(max_lw, p.log_weight);
  std::vector<double> weight(particles.size());
  double total = 0.0;
  for (size_t p = 0; p < particles.size(); ++p)
    total += weight[p] = std::exp(particles[p].log_weight - max_lw);
  for (double& w : weight) w /= total;
  return weight;
}

size_t BestIndex(const std::vector<Particle>& particles) {
  size_t best = 0;
  for (size_t i = 1; i < particles.size(); ++i) {
    if (particles[i].log_weight > particles[best].log_weight) best = i;
  }
  return best;
}

double EffectiveSampleSize(const std::vector<Particle>& particles) {
  double sum_sq = 0.0;
  for (double w : NormalizedWeights(particles)) sum_sq += w * w;
  return 1.0 / sum_sq;
}

void Resample(std::vector<Particle>& particles, size_t wanted, Rng& rng) {
  const size_t n = particles.size();
  const std::vector<double> weight = NormalizedWeights(particles);
  std::vector<size_t> order(n);
  std::iota(order.begin(), order.end(), size_t{0});
  std::stable_sort(order.begin(), order.end(),
                   [&](size_t a, size_t b) { return weight[a] > weight[b]; });
  const double u0 = rng.Uniform() / static_cast<double>(wanted);
  std::vector<Particle> next;
  next.reserve(wanted);
  double cumulative = weight[order[0]];
  size_t k = 0;
  for (size_t j = 0; j < wanted; ++j) {
    const double target = u0 + static_cast<double>(j) / static_cast<double>(wanted);
    while (cumulative < target && k + 1 < n) cumulative += weight[order[++k]];
    next.push_back(particles[order[k]]);
    next.back().log_weight = 0.0;
  }
  particles = std::move(next);
}

}  // namespace slam
