// bench-summary: the summary table of scripts/bench (docs/design.md section 9's targets), computed
// from the Google Benchmark JSON files of the suites (--benchmark_out_format=json).
//   bench-summary OUT_DIR            reads OUT_DIR/*.json
//   bench-summary a.json b.json ...  reads these files
// Prints Markdown on stdout; a benchmark that did not run gives "-". Exit status 1 when a
// benchmark reported an error (listed on stderr), 2 on unreadable input.
#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <nlohmann/json.hpp>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

namespace {

using nlohmann::json;

constexpr double kPaperScanRate = 1.5;  // scans per second (half turns of the scanner)
constexpr int kPaperBudgets[] = {8125, 16250, 32500, 65000};

/// Every benchmark run of the files, by name
/// ("BM_Scan/budget:65000/particles:1/threads:1/real_time").
class Results {
 public:
  /// Reads one JSON file; false with `error` set when it cannot.
  bool Load(const std::string& path, std::string& error) {
    std::ifstream in(path);
    if (!in) {
      error = path + ": cannot read";
      return false;
    }
    const json doc = json::parse(in, nullptr, false);
    if (doc.is_discarded() || !doc.contains("benchmarks") || !doc["benchmarks"].is_array()) {
      error = path + ": not a Google Benchmark JSON file";
      return false;
    }
    for (const json& b : doc["benchmarks"]) {
      if (!b.is_object() || !b.contains("name")) continue;
      if (b.value("run_type", "iteration") != "iteration") continue;
      if (b.value("error_occurred", false)) {
        errors_.push_back(b["name"].get<std::string>() + ": " + b.value("error_message", "error"));
        continue;
      }
      runs_[b["name"].get<std::string>()] = b;
    }
    if (context_.is_null() && doc.contains("context")) context_ = doc["context"];
    return true;
  }

  /// A field of a benchmark, if it ran.
  std::optional<double> Get(const std::string& name, const std::string& field) const {
    const auto it = runs_.find(name);
    if (it == runs_.end() || !it->second.contains(field) || !it->second[field].is_number())
      return std::nullopt;
    return it->second[field].get<double>();
  }

  /// Wall (real) time per iteration in milliseconds.
  std::optional<double> RealMs(const std::string& name) const {
    const auto t = Get(name, "real_time");
    if (!t) return std::nullopt;
    const std::string unit = runs_.at(name).value("time_unit", "ns");
    const double to_ms = unit == "s" ? 1e3 : unit == "ms" ? 1.0 : unit == "us" ? 1e-3 : 1e-6;
    return *t * to_ms;
  }

  /// A benchmark's label, if it ran ("" without one).
  std::string Label(const std::string& name) const {
    const auto it = runs_.find(name);
    return it == runs_.end() ? std::string() : it->second.value("label", std::string());
  }

  const json& context() const { return context_; }
  /// Benchmarks that reported an error (SkipWithError), as "name: message".
  const std::vector<std::string>& errors() const { return errors_; }
  size_t size() const { return runs_.size(); }

 private:
  std::map<std::string, json> runs_;
  std::vector<std::string> errors_;
  json context_;
};

std::string Fixed(double v, int digits) {
  std::ostringstream out;
  out.setf(std::ios::fixed);
  out.precision(digits);
  out << v;
  return out.str();
}

/// "12.3 M" style rates.
std::string Rate(std::optional<double> v) {
  if (!v) return "-";
  if (*v >= 1e6) return Fixed(*v / 1e6, 2) + " M";
  if (*v >= 1e3) return Fixed(*v / 1e3, 1) + " k";
  return Fixed(*v, 1);
}

std::string Ms(std::optional<double> v) { return v ? Fixed(*v, *v < 10 ? 2 : 1) : "-"; }

std::string Verdict(std::optional<double> v, double target, bool at_least) {
  if (!v) return "-";
  return (at_least ? *v >= target : *v <= target) ? "yes" : "no";
}

void PrintHelp() {
  std::cout
      << "Usage: bench-summary OUT_DIR | FILE.json...\n"
         "Prints the Markdown summary of the benchmark suites' JSON output (scripts/bench):\n"
         "rays/s per core, ms per scan at each paper budget, the real-time factor of a\n"
         "300 s replay at 65000 rays/scan, the share of one core the paper's 65000 rays/scan\n"
         "at 1.5 scans/s needs, Aseba frames/s, tile PNG encodings/s and slamd requests/s,\n"
         "each against docs/design.md section 9's target where there is one.\n";
}

}  // namespace

int main(int argc, char** argv) {
  std::vector<std::string> paths;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg == "--help" || arg == "-h") {
      PrintHelp();
      return 0;
    }
    if (std::filesystem::is_directory(arg)) {
      std::vector<std::string> found;
      for (const auto& entry : std::filesystem::directory_iterator(arg)) {
        if (entry.path().extension() == ".json") found.push_back(entry.path().string());
      }
      std::sort(found.begin(), found.end());
      paths.insert(paths.end(), found.begin(), found.end());
    } else {
      paths.push_back(arg);
    }
  }
  if (paths.empty()) {
    PrintHelp();
    return 2;
  }
  Results r;
  for (const std::string& path : paths) {
    std::string error;
    if (!r.Load(path, error)) {
      std::cerr << "bench-summary: " << error << "\n";
      return 2;
    }
  }

  const auto items = [&](const std::string& name) { return r.Get(name, "items_per_second"); };
  const auto counter = [&](const std::string& name, const std::string& c) {
    return r.Get(name, c);
  };
  const auto scan_ms = [&](int budget, int particles, int threads) {
    return r.RealMs("BM_Scan/budget:" + std::to_string(budget) +
                    "/particles:" + std::to_string(particles) +
                    "/threads:" + std::to_string(threads) + "/real_time");
  };

  // The replay: the 300 s one when it ran (full run), else the 30 s one (--ci).
  std::string replay = "BM_Replay/seconds:300/threads:1/iterations:1/real_time";
  std::string replay_note = "300 s";
  if (!r.Get(replay, "realtime_factor")) {
    replay = "BM_Replay/seconds:30/threads:1/iterations:1/real_time";
    replay_note = "30 s (CI run; the full run replays 300 s)";
  }
  const std::string replay2 =
      replay.substr(0, replay.find("/threads:")) + "/threads:2/iterations:1/real_time";
  const std::optional<double> ms65000 = scan_ms(65000, 1, 1);
  std::optional<double> share;
  if (ms65000) share = *ms65000 * kPaperScanRate / 1000.0;

  std::cout << "| what | measured | target (design 9) | met |\n|---|---:|---:|:-:|\n";
  const auto row = [](const std::string& what, const std::string& value, const std::string& target,
                      const std::string& met) {
    std::cout << "| " << what << " | " << value << " | " << target << " | " << met << " |\n";
  };
  // The engine casts a particle's candidate rays through its MatchWindow when they are many
  // (as at 65000 rays/scan), right after building it, with the fastest kernel the processor
  // runs: that is the headline; each kernel, cold windows, the tiles and the cell-by-cell
  // oracle next to it, all from the same run. A kernel the processor lacks runs the portable
  // one and says so in its label.
  const std::string window_rays = "BM_MatchingRayWindow/fill:2/length_cm:150/path:";
  const auto here = [&](const char* path) {
    const std::string label = r.Label(window_rays + path + "/engine:1");
    return !label.empty() && label.find("portable") == std::string::npos;
  };
  const bool avx512_here = here("2"), avx2_here = here("3");
  const std::string best_path = avx512_here ? "2" : avx2_here ? "3" : "1";
  const auto matching = items(window_rays + best_path + "/engine:1");
  row(std::string(
          "matching rays/s per core, <= 1.5 m at 1 cm, engine's map, through a MatchWindow as the "
          "engine casts them (") +
          (avx512_here ? "AVX-512 kernel"
           : avx2_here ? "AVX2 kernel"
                       : "portable kernel") +
          ")",
      Rate(matching), ">= 20 M", Verdict(matching, 20e6, true));
  const auto portable = items(window_rays + "1/engine:1");
  row(std::string("same rays, AVX-512 kernel (eight rays per instruction)") +
          (avx512_here ? "" : ": not on this processor"),
      avx512_here ? Rate(items(window_rays + "2/engine:1")) : "-", "", "");
  row(std::string("same rays, AVX2 kernel (four rays per instruction)") +
          (avx2_here ? "" : ": not on this processor"),
      avx2_here ? Rate(items(window_rays + "3/engine:1")) : "-", "", "");
  row("same rays, portable kernel (two rays in flight; any processor)", Rate(portable), "", "");
  row("same rays, every batch in another window (cold caches), fastest / portable kernel",
      Rate(items(window_rays + best_path + "/engine:0")) + " / " +
          Rate(items(window_rays + "1/engine:0")),
      "", "");
  const auto window_build = r.RealMs("BM_MatchWindowBuild/fill:2/length_cm:150");
  row("building that MatchWindow (3.4 m x 3.4 m, once per particle and scan), ms", Ms(window_build),
      "", "");
  const auto tiles = items(window_rays + "0/engine:1");
  row("same rays, batches through the grid's tiles (particles with few rays)", Rate(tiles), "", "");
  row("random rays from the run's poses, one at a time through the tiles (CastToObstacle)",
      Rate(items("BM_MatchingRay/fill:2/length_cm:150")), "", "");
  const auto plain = items("BM_MatchingRayPlain/fill:2/length_cm:150");
  row("same random rays, cell-by-cell traversal (the oracle; the engine before issue 7)",
      Rate(plain), "", "");
  const auto ratio = [](std::optional<double> a, std::optional<double> b) {
    return a && b && *b > 0 ? Fixed(*a / *b, 2) + "x" : std::string("-");
  };
  row("speed-up of the fastest kernel over the portable one / the tiles (same rays) / the "
      "cell-by-cell traversal "
      "(similar rays), same run",
      ratio(matching, portable) + " / " + ratio(matching, tiles) + " / " + ratio(matching, plain),
      "", "");
  const std::string room_rays = "BM_MatchingRayWindow/fill:1/length_cm:150/path:";
  const auto room = items(room_rays + best_path + "/engine:1");
  row("matching rays/s per core, <= 1.5 m at 1 cm, drawn 3 m room, window (fastest / portable "
      "kernel) / tiles",
      Rate(room) + " / " + Rate(items(room_rays + "1/engine:1")) + " / " +
          Rate(items(room_rays + "0/engine:1")),
      "", "");
  const auto room_plain = items("BM_MatchingRayPlain/fill:1/length_cm:150");
  row("speed-up of the window over the cell-by-cell traversal there, same run",
      ratio(room, room_plain), "", "");
  row("matching rays/s per core, one scan, 512 candidates",
      Rate(items("BM_MatchScan/candidates:512/threads:1/real_time")), "", "");
  row("update rays/s per core, 0.75 m reading, engine's map",
      Rate(items("BM_UpdateRay/fill:2/length_cm:75")), "", "");
  row("update rays/s per core, 1.5 m reading, engine's map",
      Rate(items("BM_UpdateRay/fill:2/length_cm:150")), "", "");
  const auto rtf = counter(replay, "realtime_factor");
  row("real-time factor, replay of " + replay_note + " at 65000 rays/scan, 1 core",
      rtf ? Fixed(*rtf, 1) + "x" : "-", ">= 100x", Verdict(rtf, 100.0, true));
  const auto rtf2 = counter(replay2, "realtime_factor");
  row("real-time factor, same replay, 2 threads", rtf2 ? Fixed(*rtf2, 1) + "x" : "-", "", "");
  row("ms per scan at 65000 rays/scan, 1 particle, 1 core", Ms(ms65000), "", "");
  row("share of one core for 65000 rays/scan at 1.5 scans/s",
      share ? Fixed(*share * 100.0, 1) + " %" : "-", "<= 5 %", Verdict(share, 0.05, false));
  const auto aseba = items("BM_AsebaDecode");
  row("Aseba frame decoding (reassembly + events), frames/s", Rate(aseba), ">= 5 M",
      Verdict(aseba, 5e6, true));
  row("Aseba reassembly alone, frames/s", Rate(items("BM_AsebaReassembly")), "", "");
  row("candump lines parsed, frames/s", Rate(items("BM_CandumpParse")), "", "");
  row("candump log to robot events, frames/s", Rate(items("BM_CandumpToEvents")), "", "");
  row("slcan stream parsed (64-byte reads), frames/s", Rate(items("BM_SlcanParse/read_bytes:64")),
      "", "");
  row("tile PNG encodings/s (64 x 64 grey)", Rate(items("BM_TilePng")), "", "");
  row("slamd GET /api/v1/status, requests/s, 1 client",
      Rate(items("BM_SlamdRequest/route:1/real_time/threads:1")), "", "");
  row("slamd GET tile PNG, requests/s, 1 client",
      Rate(items("BM_SlamdRequest/route:4/real_time/threads:1")), "", "");
  const auto fitness = r.RealMs("BM_TunerFitness/seconds:300/budget:8125/iterations:1/real_time");
  const auto fitness65 =
      r.RealMs("BM_TunerFitness/seconds:300/budget:65000/iterations:1/real_time");
  if (fitness || fitness65) {
    row("tuner fitness evaluation, 300 s experiment, 8125 / 65000 rays/scan, s",
        (fitness ? Fixed(*fitness / 1e3, 2) : "-") + " / " +
            (fitness65 ? Fixed(*fitness65 / 1e3, 2) : "-"),
        "", "");
  } else {
    const auto short_fitness =
        r.RealMs("BM_TunerFitness/seconds:30/budget:8125/iterations:1/real_time");
    row("tuner fitness evaluation, 30 s experiment (CI run), 8125 rays/scan, s",
        short_fitness ? Fixed(*short_fitness / 1e3, 2) : "-", "", "");
  }
  std::cout << "\nWhole scans of the rooms run (phases A-D, fixed policy), ms per scan (wall):\n\n"
               "| rays/scan | 1 particle | 5 particles | 1 particle, 2 threads | 5 particles, 2 "
               "threads | share of one core at 1.5 scans/s (1 particle) |\n"
               "|---:|---:|---:|---:|---:|---:|\n";
  for (const int budget : kPaperBudgets) {
    const auto one = scan_ms(budget, 1, 1);
    std::cout << "| " << budget << " | " << Ms(one) << " | " << Ms(scan_ms(budget, 5, 1)) << " | "
              << Ms(scan_ms(budget, 1, 2)) << " | " << Ms(scan_ms(budget, 5, 2)) << " | "
              << (one ? Fixed(*one * kPaperScanRate / 10.0, 1) + " %" : "-") << " |\n";
  }
  const json& context = r.context();
  if (context.is_object() && !context.empty()) {
    std::cout << "\n"
              << r.size() << " benchmarks; " << context.value("host_name", "?") << ", "
              << context.value("num_cpus", 0) << " CPUs at " << context.value("mhz_per_cpu", 0)
              << " MHz, " << context.value("date", "?") << ".\n";
  }
  for (const std::string& error : r.errors())
    std::cerr << "bench-summary: failed: " << error << "\n";
  return r.errors().empty() ? 0 : 1;
}
