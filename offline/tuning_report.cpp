#include "offline/tuning_report.hpp"

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <limits>

#include "engine/io/atomic_file.hpp"
#include "engine/io/map_image.hpp"
#include "engine/io/params_json.hpp"
#include "offline/tuning_plot.hpp"

namespace slam::offline {
namespace {

using Json = nlohmann::json;

constexpr const char* kFormat = "slam-tune results 1";

Json SettingsToJson(const TuningSettings& s) {
  return {{"budgets", s.budgets},
          {"population", s.evolution.population},
          {"generations", s.evolution.generations},
          {"elite_fraction", s.evolution.elite_fraction},
          {"min_rays_per_particle", s.evolution.min_rays_per_particle},
          {"seed", s.evolution.seed},
          {"policy", std::string(ToString(s.policy))},
          {"max_particles", s.max_particles},
          {"racing", s.racing},
          {"race_alpha", s.race_alpha},
          {"start", io::ParamsToJson(s.start)}};
}

Json IndividualToJson(const Individual& i) {
  Json j = {{"fitness", i.fitness}, {"params", io::ParamsToJson(i.params)}};
  if (i.raced_out) j["raced_out"] = true;  // its fitness is a lower bound
  if (!i.scores.empty()) j["scores"] = i.scores;
  return j;
}

/// Thrown inside the reader only, turned into an error at its boundary.
struct ReadError {
  std::string pointer, detail;
};

SlamParams ParamsAt(const Json& json, const std::string& pointer) {
  const Result<SlamParams> params = io::ParamsFromJson(json);
  if (!params.ok()) throw ReadError{pointer, params.Message()};
  return params.value();
}

Individual IndividualAt(const Json& json, const std::string& pointer) {
  Individual i;
  i.fitness = json.at("fitness").get<double>();
  i.params = ParamsAt(json.at("params"), pointer + "/params");
  i.evaluated = true;
  i.raced_out = json.value("raced_out", false);
  if (const auto scores = json.find("scores"); scores != json.end()) {  // absent before racing
    for (const Json& e : *scores) {  // null: an experiment racing did not replay
      i.scores.push_back(e.is_null() ? std::numeric_limits<double>::quiet_NaN() : e.get<double>());
    }
  }
  return i;
}

std::string Fixed(double value, int decimals) {
  char text[64];
  std::snprintf(text, sizeof(text), "%.*f", decimals, value);
  return text;
}

/// A parameter value as Table II prints it.
std::string ParameterText(const ParameterSpec& spec, double value) {
  if (spec.integer) return std::to_string(static_cast<long long>(std::llround(value)));
  return Fixed(value, value != 0.0 && std::abs(value) < 0.01 ? 4 : 3);
}

std::string PValueText(double p) {
  char text[32];
  if (p < 1e-4) {
    std::snprintf(text, sizeof(text), "%.1e", p);
  } else {
    std::snprintf(text, sizeof(text), "%.4f", p);
  }
  return text;
}

}  // namespace

Json TuningStateToJson(const TuningState& state) {
  Json j;
  j["format"] = kFormat;
  j["settings"] = SettingsToJson(state.settings);
  j["experiments"] = state.experiments;
  j["ranks"] = state.ranks;  // processes of the last run (MPI ranks); results never depend on it
  Json budgets = Json::array();
  for (const BudgetRun& run : state.budgets) {
    Json b;
    b["budget"] = run.budget;
    Json generations = Json::array();
    for (const GenerationSummary& g : run.generations) {
      generations.push_back({{"generation", g.generation},
                             {"min", g.fitness.min},
                             {"q1", g.fitness.q1},
                             {"median", g.fitness.median},
                             {"q3", g.fitness.q3},
                             {"max", g.fitness.max},
                             {"evaluations", g.evaluations},
                             {"cost",
                              {{"replays", g.replays},
                               {"scans", g.scans},
                               {"replays_saved", g.replays_saved},
                               {"scans_saved", g.scans_saved},
                               {"raced_out", g.raced_out}}},
                             {"best", IndividualToJson(g.best)}});
    }
    b["generations"] = generations;
    if (!run.generations.empty()) {
      b["best"] = IndividualToJson(run.generations.back().best);
      b["last_generation"] = {{"generation", run.generations.back().generation},
                              {"fitness", run.generations.back().fitness_values}};
    }
    Json population = Json::array();
    for (const Individual& i : run.population) population.push_back(IndividualToJson(i));
    b["population"] = population;
    budgets.push_back(b);
  }
  j["budgets"] = budgets;
  return j;
}

Result<TuningState> TuningStateFromJson(const Json& json) {
  try {
    if (json.value("format", std::string()) != kFormat) {
      return ConfigErrors{
          {"/format", std::string("not \"") + kFormat + "\": not a slam-tune result"}};
    }
    TuningState state;
    const Json& s = json.at("settings");
    state.settings.budgets = s.at("budgets").get<std::vector<int64_t>>();
    state.settings.evolution.population = s.at("population").get<int>();
    state.settings.evolution.generations = s.at("generations").get<int>();
    state.settings.evolution.elite_fraction = s.at("elite_fraction").get<double>();
    // Absent in results written before the bound existed: no bound.
    state.settings.evolution.min_rays_per_particle = s.value("min_rays_per_particle", int64_t{0});
    state.settings.evolution.seed = s.at("seed").get<uint64_t>();
    const auto policy = ParseBudgetPolicy(s.at("policy").get<std::string>());
    if (!policy) throw ReadError{"/settings/policy", "unknown policy"};
    state.settings.policy = *policy;
    state.settings.max_particles = s.at("max_particles").get<int>();
    // Absent before racing existed: those studies ran without it.
    state.settings.racing = s.value("racing", false);
    state.settings.race_alpha = s.value("race_alpha", 0.0);
    state.settings.start = ParamsAt(s.at("start"), "/settings/start");
    state.experiments = json.at("experiments").get<std::vector<std::string>>();
    state.ranks = json.value("ranks", 1);
    const Json& budgets = json.at("budgets");
    if (!budgets.is_array() || budgets.size() != state.settings.budgets.size()) {
      throw ReadError{"/budgets", "one entry per budget of the settings expected"};
    }
    for (size_t b = 0; b < budgets.size(); ++b) {
      const std::string at = "/budgets/" + std::to_string(b);
      BudgetRun run;
      run.budget = budgets[b].at("budget").get<int64_t>();
      if (run.budget != state.settings.budgets[b])
        throw ReadError{at + "/budget", "not the settings' budget"};
      const Json& generations = budgets[b].at("generations");
      for (size_t g = 0; g < generations.size(); ++g) {
        const Json& gj = generations.at(g);
        GenerationSummary summary;
        summary.generation = gj.at("generation").get<int>();
        if (summary.generation != static_cast<int>(g)) {
          throw ReadError{at + "/generations/" + std::to_string(g), "generations out of order"};
        }
        summary.fitness = {gj.at("min").get<double>(), gj.at("q1").get<double>(),
                           gj.at("median").get<double>(), gj.at("q3").get<double>(),
                           gj.at("max").get<double>()};
        summary.evaluations = gj.at("evaluations").get<int>();
        if (const auto cost = gj.find("cost"); cost != gj.end()) {  // absent before racing
          summary.replays = cost->at("replays").get<int64_t>();
          summary.scans = cost->at("scans").get<int64_t>();
          summary.replays_saved = cost->at("replays_saved").get<int64_t>();
          summary.scans_saved = cost->at("scans_saved").get<int64_t>();
          summary.raced_out = cost->at("raced_out").get<int>();
        }
        summary.best =
            IndividualAt(gj.at("best"), at + "/generations/" + std::to_string(g) + "/best");
        run.generations.push_back(summary);
      }
      if (!run.generations.empty()) {
        run.generations.back().fitness_values =
            budgets[b].at("last_generation").at("fitness").get<std::vector<double>>();
      }
      const Json& population = budgets[b].at("population");
      for (size_t i = 0; i < population.size(); ++i) {
        run.population.push_back(
            IndividualAt(population.at(i), at + "/population/" + std::to_string(i)));
      }
      if (!run.generations.empty() &&
          (run.population.size() != static_cast<size_t>(state.settings.evolution.population) ||
           run.generations.back().fitness_values.size() != run.population.size())) {
        throw ReadError{at + "/population", "the last generation's population is incomplete"};
      }
      state.budgets.push_back(std::move(run));
    }
    return state;
  } catch (const ReadError& e) {
    return ConfigErrors{{e.pointer, e.detail}};
  } catch (const Json::exception& e) {
    return ConfigErrors{{"", std::string("not a complete slam-tune result: ") + e.what()}};
  }
}

std::vector<std::string> ResumeConflicts(const TuningState& saved, const TuningSettings& settings,
                                         const std::vector<std::string>& experiments) {
  std::vector<std::string> conflicts;
  Json a = SettingsToJson(saved.settings), b = SettingsToJson(settings);
  // Neither the generation count (a study can be extended) nor racing on or off must match:
  // racing's bound never changes the elites, so a study may go on with it or without; its
  // test's level must (it can change them), unless racing is off on either side.
  const bool test_matters = a.value("racing", false) && b.value("racing", false);
  for (const char* free_key : {"generations", "racing"}) {
    a.erase(free_key);
    b.erase(free_key);
  }
  if (!test_matters) {
    a.erase("race_alpha");
    b.erase("race_alpha");
  }
  for (const auto& [key, value] : b.items()) {
    if (a[key] != value)
      conflicts.push_back(key + ": saved " + a[key].dump() + ", asked " + value.dump());
  }
  if (saved.experiments != experiments) {
    conflicts.push_back("experiments: saved " + Json(saved.experiments).dump() + ", asked " +
                        Json(experiments).dump());
  }
  return conflicts;
}

std::string Table2Markdown(const TuningState& state) {
  std::string md = "# Best parameters per budget (like the paper's Table II)\n\n";
  md += "Evolution strategy: population " + std::to_string(state.settings.evolution.population) +
        ", elitism " + Fixed(100.0 * state.settings.evolution.elite_fraction, 0) + " %, seed " +
        std::to_string(state.settings.evolution.seed) + ", policy " +
        std::string(ToString(state.settings.policy)) + ", " +
        std::to_string(state.experiments.size()) +
        " experiments. Fitness: mean of e = log(1 - q) (lower is better).\n\n";
  md += "| parameter | default |";
  std::string rule = "|---|---:|";
  for (const BudgetRun& run : state.budgets) {
    md += " " + std::to_string(run.budget) + " |";
    rule += "---:|";
  }
  md += "\n" + rule + "\n";
  const auto& specs = TunedParameters();
  for (size_t i = 0; i < specs.size(); ++i) {
    md += "| `" + std::string(specs[i].key) + "` | " +
          ParameterText(specs[i], GetParameter(state.settings.start, i)) + " |";
    for (const BudgetRun& run : state.budgets) {
      md += run.generations.empty()
                ? " - |"
                : " " +
                      ParameterText(specs[i], GetParameter(run.generations.back().best.params, i)) +
                      " |";
    }
    md += "\n";
  }
  md += "| best fitness | |";
  for (const BudgetRun& run : state.budgets) {
    md += run.generations.empty() ? " - |"
                                  : " " + Fixed(run.generations.back().best.fitness, 4) + " |";
  }
  md += "\n| generations | |";
  for (const BudgetRun& run : state.budgets)
    md += " " + std::to_string(run.generations.size()) + " |";
  md += "\n";
  return md;
}

std::string Table3Markdown(const TuningState& state) {
  std::string md = "# Mann-Whitney U between budgets (like the paper's Table III)\n\n";
  md +=
      "Two-sided p-values between the fitness values of the last generations (exact permutation "
      "distribution with ties when the samples total 120 or fewer, else the normal approximation "
      "with tie correction). Small p: the budgets' final populations differ.\n\n";
  std::vector<const BudgetRun*> done;
  for (const BudgetRun& run : state.budgets) {
    if (!run.generations.empty() && !run.generations.back().fitness_values.empty())
      done.push_back(&run);
  }
  if (done.size() < 2) return md + "Fewer than two budgets have a generation yet.\n";
  md += "| budget |";
  std::string rule = "|---:|";
  for (size_t j = 1; j < done.size(); ++j) {
    md += " " + std::to_string(done[j]->budget) + " |";
    rule += "---:|";
  }
  md += "\n" + rule + "\n";
  for (size_t i = 0; i + 1 < done.size(); ++i) {
    md += "| " + std::to_string(done[i]->budget) + " |";
    for (size_t j = 1; j < done.size(); ++j) {
      if (j <= i) {
        md += " |";
        continue;
      }
      const MannWhitneyResult r = MannWhitneyU(done[i]->generations.back().fitness_values,
                                               done[j]->generations.back().fitness_values);
      md += " " + PValueText(r.p_value) + (r.exact ? "" : " (normal)") + " |";
    }
    md += "\n";
  }
  // Generations are numbered from 1 where people read them, as on slam-tune's console and in
  // Fig. 10 (results.json keeps the 0-based index it resumes from).
  md += "\nLast generations:";
  for (const BudgetRun* run : done) {
    md += " " + std::to_string(run->budget) + " at generation " +
          std::to_string(run->generations.back().generation + 1) + " (median " +
          Fixed(run->generations.back().fitness.median, 4) + ")" + (run == done.back() ? "." : ";");
  }
  return md + "\n";
}

std::vector<std::string> WriteTuningOutputs(const std::string& dir, const TuningState& state) {
  std::vector<std::string> errors;
  const auto write = [&](const std::string& name, const std::string& text) {
    const Result<void> written =
        io::WriteFileAtomic((std::filesystem::path(dir) / name).string(), text);
    if (!written.ok()) errors.push_back(written.Message());
  };
  write("results.json", TuningStateToJson(state).dump(1) + "\n");
  write("table2.md", Table2Markdown(state));
  write("table3.md", Table3Markdown(state));

  std::vector<TuningSeries> series;
  for (const BudgetRun& run : state.budgets) {
    TuningSeries s;
    s.label = std::to_string(run.budget) + " rays/scan";
    for (const GenerationSummary& g : run.generations)
      s.generations.push_back({g.fitness.q1, g.fitness.median, g.fitness.q3});
    series.push_back(std::move(s));
  }
  TuningPlotOptions options;
  options.title =
      "Fitness per generation (" + std::string(ToString(state.settings.policy)) + " policy)";
  write("fig10.svg", TuningPlotSvg(series, options));
  const Result<void> plotted = io::WritePng((std::filesystem::path(dir) / "fig10.png").string(),
                                            TuningPlotImage(series, options));
  if (!plotted.ok()) errors.push_back(plotted.Message());

  std::error_code ec;
  const std::filesystem::path params_dir = std::filesystem::path(dir) / "params";
  std::filesystem::create_directories(params_dir, ec);
  if (ec) {
    errors.push_back("cannot create " + params_dir.string() + ": " + ec.message());
    return errors;
  }
  for (const BudgetRun& run : state.budgets) {
    if (run.generations.empty()) continue;
    write("params/" + std::to_string(run.budget) + ".json",
          io::ParamsToJson(run.generations.back().best.params).dump(2) + "\n");
  }
  return errors;
}

}  // namespace slam::offline
