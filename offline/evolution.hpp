#pragma once
// The paper's evolution strategy over the SLAM parameters (section VI-B): a population of
// parameter sets; each generation keeps the best quarter unchanged (elitism) and fills the rest
// with Gaussian mutations of them (sigmas of docs/design.md section 3), clamped to bounds, the
// integer parameters rounded. Every random draw depends only on (seed, stream, generation), so a
// run gives the same result whatever the thread count, and resumes exactly from a saved generation.

#include <cstdint>
#include <string_view>
#include <vector>

#include "engine/params.hpp"
#include "engine/random.hpp"

namespace slam::offline {

/// One tuned parameter: its JSON key, mutation sigma and search bounds.
struct ParameterSpec {
  std::string_view key;
  double sigma;
  double lo, hi;
  bool integer;
};

/// The nine parameters of Table II, in its order.
const std::vector<ParameterSpec>& TunedParameters();

/// A parameter's value by its position in TunedParameters(), and the reverse.
double GetParameter(const SlamParams& params, size_t index);
void SetParameter(SlamParams& params, size_t index, double value);

struct EvolutionConfig {
  int population = 48;
  int generations = 40;
  double elite_fraction = 0.25;
  uint64_t seed = 1;
  /// Each particle's share of the budget is at least this many rays (0: no bound): the particle
  /// count is tuned within [1, max(1, budget / min_rays_per_particle)]. At a fixed budget more
  /// particles mean fewer rays each, below what pays for a particle's match window, so the CPU
  /// per scan grows with the count (docs/accuracy.md): the bound keeps a budget's cost its own.
  int64_t min_rays_per_particle = 0;

  /// Individuals kept unchanged from one generation to the next (at least 1).
  int elites() const;
  /// The most particles an individual tuned for `budget` may have.
  int MaxParticles(int64_t budget) const;
};

/// Empty when valid.
ConfigErrors Validate(const EvolutionConfig& config);

struct Individual {
  SlamParams params;
  double fitness = 0.0;  // lower is better (the tuner's: mean e over the experiments)
  bool evaluated = false;
  /// Racing stopped its evaluation once it could no longer enter the elite (RunTuning):
  /// `fitness` is then above the elite's worst, a lower bound on its mean e (or, stopped by
  /// racing's test, its estimate from the experiments replayed), and it never ranks among the
  /// individuals evaluated whole.
  bool raced_out = false;
  /// e of each experiment replayed, in the experiments' order (when raced out, the last one is
  /// the bound its replay stopped at); racing compares new individuals with these.
  std::vector<double> scores{};
};

/// The particle bound of the tuned parameters (TunedParameters()).
inline constexpr int kMaxTunedParticles = 64;

/// `params` with every tuned parameter moved by a Gaussian draw of its sigma, clamped to its
/// bounds (the particle count also to `max_particles`), integers rounded.
SlamParams Mutate(const SlamParams& params, Rng& rng, int max_particles = kMaxTunedParticles);

/// Generation 0: `start` itself (its particles clamped to `max_particles`), then mutations of it.
/// `stream` tells budgets apart.
std::vector<Individual> InitialPopulation(const SlamParams& start, const EvolutionConfig& config,
                                          uint64_t stream, int max_particles = kMaxTunedParticles);

/// Ranks an evaluated population, best first (stable: ties keep their order); individuals that
/// racing stopped come after every other.
std::vector<Individual> Ranked(std::vector<Individual> population);

/// Generation `generation` (>= 1) from the evaluated previous one: its elites unchanged (with
/// their fitness, not evaluated again), then mutations of elites drawn uniformly.
std::vector<Individual> NextGeneration(const std::vector<Individual>& previous,
                                       const EvolutionConfig& config, uint64_t stream,
                                       int generation, int max_particles = kMaxTunedParticles);

}  // namespace slam::offline
