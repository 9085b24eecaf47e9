#include "offline/evolution.hpp"

#include <algorithm>
#include <cmath>
#include <string>

#include "engine/random.hpp"

namespace slam::offline {
namespace {

// Random streams: generation 0's mutations, and every later generation's choices.
constexpr uint64_t kStreamEvolution = 0x45530000;  // "ES"

}  // namespace

const std::vector<ParameterSpec>& TunedParameters() {
  // Sigmas: docs/design.md section 3 (paper Table II). Bounds: the physically meaningful range,
  // within Validate(SlamParams); a minimum uncertainty of 0 would make refinement a no-op.
  static const std::vector<ParameterSpec> specs = {
      {"dist_error_ratio", 0.01, 0.0, 0.5, false},
      {"dist_error_const_m", 0.002, 0.0, 0.1, false},
      {"angle_error_ratio", 0.01, 0.0, 0.5, false},
      {"angle_error_const_deg", 0.002, 0.0, 5.0, false},
      {"min_pos_uncertainty_m", 0.004, 0.001, 0.2, false},
      {"min_angle_uncertainty_deg", 1.0, 0.1, 30.0, false},
      {"resampling_period_scans", 0.5, 1.0, 50.0, true},
      {"angle_between_scans_deg", 2.5, 0.0, 45.0, false},
      {"particles", 1.0, 1.0, kMaxTunedParticles, true},
  };
  return specs;
}

double GetParameter(const SlamParams& p, size_t index) {
  switch (index) {
    case 0:
      return p.dist_error_ratio;
    case 1:
      return p.dist_error_const_m;
    case 2:
      return p.angle_error_ratio;
    case 3:
      return p.angle_error_const_deg;
    case 4:
      return p.min_pos_uncertainty_m;
    case 5:
      return p.min_angle_uncertainty_deg;
    case 6:
      return p.resampling_period_scans;
    case 7:
      return p.angle_between_scans_deg;
    default:
      return p.particles;
  }
}

void SetParameter(SlamParams& p, size_t index, double value) {
  switch (index) {
    case 0:
      p.dist_error_ratio = value;
      break;
    case 1:
      p.dist_error_const_m = value;
      break;
    case 2:
      p.angle_error_ratio = value;
      break;
    case 3:
      p.angle_error_const_deg = value;
      break;
    case 4:
      p.min_pos_uncertainty_m = value;
      break;
    case 5:
      p.min_angle_uncertainty_deg = value;
      break;
    case 6:
      p.resampling_period_scans = static_cast<int>(value);
      break;
    case 7:
      p.angle_between_scans_deg = value;
      break;
    default:
      p.particles = static_cast<int>(value);
      break;
  }
}

int EvolutionConfig::elites() const {
  return std::clamp(static_cast<int>(std::lround(elite_fraction * population)), 1,
                    std::max(1, population));
}

int EvolutionConfig::MaxParticles(int64_t budget) const {
  if (min_rays_per_particle <= 0) return kMaxTunedParticles;
  return static_cast<int>(
      std::clamp<int64_t>(budget / min_rays_per_particle, 1, kMaxTunedParticles));
}

ConfigErrors Validate(const EvolutionConfig& config) {
  ConfigErrors errors;
  if (config.population < 2 || config.population > 100000) {
    errors.push_back(
        {"/population", std::to_string(config.population) + " is outside [2, 100000]"});
  }
  if (config.generations < 1 || config.generations > 100000) {
    errors.push_back(
        {"/generations", std::to_string(config.generations) + " is outside [1, 100000]"});
  }
  if (!(config.elite_fraction > 0.0 && config.elite_fraction < 1.0)) {
    errors.push_back(
        {"/elite_fraction", std::to_string(config.elite_fraction) + " is outside (0, 1)"});
  }
  if (config.min_rays_per_particle < 0) {
    errors.push_back(
        {"/min_rays_per_particle", std::to_string(config.min_rays_per_particle) + " is negative"});
  }
  return errors;
}

SlamParams Mutate(const SlamParams& params, Rng& rng, int max_particles) {
  SlamParams out = params;
  const auto& specs = TunedParameters();
  for (size_t i = 0; i < specs.size(); ++i) {
    double value = GetParameter(params, i) + rng.Gaussian(specs[i].sigma);
    if (specs[i].integer) value = std::round(value);
    SetParameter(out, i, std::clamp(value, specs[i].lo, specs[i].hi));
  }
  out.particles = std::clamp(out.particles, 1, std::max(1, max_particles));
  return out;
}

std::vector<Individual> InitialPopulation(const SlamParams& start, const EvolutionConfig& config,
                                          uint64_t stream, int max_particles) {
  std::vector<Individual> population;
  SlamParams first = start;
  first.particles = std::clamp(first.particles, 1, std::max(1, max_particles));
  population.push_back({first, 0.0, false});
  for (int i = 1; i < config.population; ++i) {
    Rng rng = Rng::ForStream(config.seed, kStreamEvolution + stream, 0, static_cast<uint64_t>(i));
    population.push_back({Mutate(first, rng, max_particles), 0.0, false});
  }
  return population;
}

std::vector<Individual> Ranked(std::vector<Individual> population) {
  std::stable_sort(population.begin(), population.end(),
                   [](const Individual& a, const Individual& b) {
                     if (a.raced_out != b.raced_out) return b.raced_out;
                     return a.fitness < b.fitness;
                   });
  return population;
}

std::vector<Individual> NextGeneration(const std::vector<Individual>& previous,
                                       const EvolutionConfig& config, uint64_t stream,
                                       int generation, int max_particles) {
  const std::vector<Individual> ranked = Ranked(previous);
  const size_t elites = std::min(ranked.size(), static_cast<size_t>(config.elites()));
  std::vector<Individual> next(ranked.begin(),
                               ranked.begin() + static_cast<std::ptrdiff_t>(elites));
  for (int i = static_cast<int>(elites); i < config.population; ++i) {
    Rng rng = Rng::ForStream(config.seed, kStreamEvolution + stream,
                             static_cast<uint64_t>(generation), static_cast<uint64_t>(i));
    const size_t parent =
        std::min(elites - 1, static_cast<size_t>(rng.Uniform() * static_cast<double>(elites)));
    next.push_back({Mutate(ranked[parent].params, rng, max_particles), 0.0, false});
  }
  return next;
}

}  // namespace slam::offline
