// The command line of slamd and the tools, as a user meets it (issue 46, item 12): a mistyped
// option answered with the nearest real one, an unknown world answered with every built-in one,
// slam-evaluate on a study that tuned only some budgets, generations numbered from 1 where
// people read them, slam-relations saying why a file cannot be read, and the README's outputs
// ignored by git. The tools run as child processes; stdout and stderr are checked.

#include <fcntl.h>
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <regex>
#include <set>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "engine/io/params_json.hpp"
#include "offline/evaluation.hpp"
#include "offline/tuner.hpp"
#include "offline/tuning_report.hpp"
#include "sim/world.hpp"
#include "tools/command_line.hpp"

namespace slam {
namespace {

namespace fs = std::filesystem;
using Json = nlohmann::json;

struct ToolRun {
  int status = -1;  // exit status; -1 when killed or not run
  std::string out, err;
};

std::string ReadAll(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream text;
  text << in.rdbuf();
  return text.str();
}

/// A fresh empty directory for one test's files.
fs::path Scratch(const std::string& name) {
  const fs::path dir =
      fs::temp_directory_path() / ("slam-cli-test-" + std::to_string(::getpid()) + "-" + name);
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

/// Runs `argv` (no shell) in `dir`, its output in files there; killed after 60 s.
ToolRun RunTool(const std::vector<std::string>& argv, const fs::path& dir) {
  const fs::path out = dir / "stdout.txt", err = dir / "stderr.txt";
  const pid_t pid = ::fork();
  if (pid == 0) {
    const int o = ::open(out.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    const int e = ::open(err.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    if (o < 0 || e < 0 || ::dup2(o, 1) < 0 || ::dup2(e, 2) < 0 || ::chdir(dir.c_str()) != 0)
      ::_exit(127);
    std::vector<char*> args;
    for (const std::string& a : argv) args.push_back(const_cast<char*>(a.c_str()));
    args.push_back(nullptr);
    ::execv(args[0], args.data());
    ::_exit(127);
  }
  ToolRun run;
  if (pid < 0) return run;
  int status = 0;
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(60);
  while (::waitpid(pid, &status, WNOHANG) == 0) {
    if (std::chrono::steady_clock::now() > deadline) {
      ::kill(pid, SIGKILL);
      ::waitpid(pid, &status, 0);
      break;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  if (WIFEXITED(status)) run.status = WEXITSTATUS(status);
  run.out = ReadAll(out);
  run.err = ReadAll(err);
  return run;
}

// --- "did you mean" -------------------------------------------------------------------------

TEST(CommandLineTest, EditDistanceCountsASwapOfNeighboursAsOne) {
  EXPECT_EQ(cli::EditDistance("budgte", "budget"), 1u);
  EXPECT_EQ(cli::EditDistance("budget", "budget"), 0u);
  EXPECT_EQ(cli::EditDistance("", "abc"), 3u);
  EXPECT_EQ(cli::EditDistance("abc", ""), 3u);
  EXPECT_EQ(cli::EditDistance("kitten", "sitting"), 3u);
  EXPECT_EQ(cli::EditDistance("--Budget", "--budget"), 0u);  // case is not a slip worth counting
  EXPECT_EQ(cli::EditDistance("ca", "abc"), 3u);  // optimal string alignment, not Damerau's
}

TEST(CommandLineTest, NearestNamesSuggestsOnlyWhatIsNear) {
  const std::vector<std::string> options = {"--budget", "--seed", "--speed",    "--out",
                                            "-h",       "--help", "--relations"};
  EXPECT_EQ(cli::NearestNames("--budgte", options), std::vector<std::string>{"--budget"});
  EXPECT_EQ(cli::NearestNames("-budget", options), std::vector<std::string>{"--budget"});
  EXPECT_EQ(cli::NearestNames("--ot", options), std::vector<std::string>{"--out"});
  EXPECT_EQ(cli::NearestNames("--rel", options), std::vector<std::string>{"--relations"});
  EXPECT_EQ(cli::NearestNames("--sped", options), (std::vector<std::string>{"--seed", "--speed"}));
  EXPECT_TRUE(cli::NearestNames("--xyzzy", options).empty());
  EXPECT_TRUE(cli::NearestNames("-x", options).empty());  // one letter is no evidence
  EXPECT_TRUE(cli::NearestNames("--s", options).empty());
  EXPECT_EQ(cli::DidYouMean({"--seed", "--speed"}), "(did you mean --seed or --speed?)");
}

struct Typo {
  const char* binary;
  std::vector<std::string> args;
  const char* expected;  // the line on stderr, after "<tool>: "
};

TEST(CommandLineTest, NumbersAndPosesAreTakenWholeAndFiniteOrNotAtAll) {
  using slam::cli::FiniteNumber;
  using slam::cli::FiniteNumbers;
  using slam::cli::PoseArgument;
  EXPECT_EQ(FiniteNumber("0.5"), 0.5);
  EXPECT_EQ(FiniteNumber("-1e-3"), -1e-3);
  for (const char* bad : {"", " ", "1x", "x1", "nan", "inf", "-inf", "1e999", "1,"})
    EXPECT_FALSE(FiniteNumber(bad)) << bad;

  EXPECT_EQ(FiniteNumbers("1:2", ':', 2), (std::vector<double>{1.0, 2.0}));
  for (const char* bad : {"1", "1:2:3", "1:", ":2", "1::2", "1:nan", "1,2"})
    EXPECT_FALSE(FiniteNumbers(bad, ':', 2)) << bad;

  const std::optional<slam::Pose2> pose = PoseArgument("1.5,-2,270");
  ASSERT_TRUE(pose);
  EXPECT_DOUBLE_EQ(pose->x, 1.5);
  EXPECT_DOUBLE_EQ(pose->y, -2.0);
  EXPECT_NEAR(pose->theta, -slam::kPi / 2.0, 1e-12);  // normalised
  for (const char* bad : {"1,2", "1,2,3,4", "a,b,c", "0,nan,0", "0,0,inf", "1,2,3,", ",1,2"})
    EXPECT_FALSE(PoseArgument(bad)) << bad;
}

TEST(CommandLineTest, EveryToolAnswersAMistypedOptionWithTheNearestOfItsOwn) {
  const fs::path dir = Scratch("typos");
  const std::vector<Typo> typos = {
      {SLAMD_BIN, {"--budgte", "100"}, "unknown option --budgte (did you mean --budget?)"},
      {SLAM_REPLAY_BIN, {"--budgte", "100"}, "unknown option --budgte (did you mean --budget?)"},
      {SLAM_SIM_BIN, {"--wrold", "rooms"}, "unknown option --wrold (did you mean --world?)"},
      {SLAM_SIM_BIN,
       {"dataset", "--st", "all", "--out", "x"},
       "unknown option --st (did you mean --set?)"},
      // Its DIRS and --out are missing too: the typo is the cause and is what is said.
      {SLAM_EVALUATE_BIN, {"--bugdets=5"}, "unknown option --bugdets (did you mean --budgets?)"},
      {SLAM_TUNE_BIN,
       {"--populaton", "4"},
       "unknown option --populaton (did you mean --population?)"},
      {SLAM_RELATIONS_BIN,
       {"a.tum", "--relatoins", "r.txt"},
       "unknown option --relatoins (did you mean --relations?)"},
      {SLAM_LINK_BIN, {"--sorce", "sim:box"}, "unknown option --sorce (did you mean --source?)"},
      {SLAMD_LOAD_BIN,
       {"--url", "http://127.0.0.1:1/", "--viewrs", "2"},
       "unknown option --viewrs (did you mean --viewers?)"},
  };
  for (const Typo& typo : typos) {
    std::vector<std::string> argv = {typo.binary};
    argv.insert(argv.end(), typo.args.begin(), typo.args.end());
    const ToolRun run = RunTool(argv, dir);
    const std::string tool = fs::path(typo.binary).filename().string();
    EXPECT_EQ(run.status, static_cast<int>(CLI::ExitCodes::ExtrasError)) << tool << run.err;
    EXPECT_NE(run.err.find(tool + ": " + typo.expected + "\n"), std::string::npos) << tool << ":\n"
                                                                                   << run.err;
    EXPECT_EQ(run.err.find("not expected"), std::string::npos) << run.err;
    EXPECT_EQ(run.out, "") << tool;
  }
}

TEST(CommandLineTest, AnOptionWithNothingNearIsStillNamedAndHelpStillWorks) {
  const fs::path dir = Scratch("far");
  const ToolRun far = RunTool({SLAM_SIM_BIN, "--xyzzy"}, dir);
  EXPECT_EQ(far.status, static_cast<int>(CLI::ExitCodes::ExtrasError));
  EXPECT_NE(far.err.find("slam-sim: unknown option --xyzzy\n"), std::string::npos) << far.err;
  EXPECT_NE(far.err.find("--help"), std::string::npos) << far.err;
  const ToolRun help = RunTool({SLAM_SIM_BIN, "--help"}, dir);
  EXPECT_EQ(help.status, 0);
  EXPECT_NE(help.out.find("--world"), std::string::npos);
  const ToolRun version = RunTool({SLAM_SIM_BIN, "--version"}, dir);
  EXPECT_EQ(version.status, 0);
  EXPECT_EQ(version.out.rfind("slam-sim ", 0), 0u) << version.out;
  // Other parse errors are CLI11's own, unchanged.
  const ToolRun range =
      RunTool({SLAM_SIM_BIN, "--duration", "-5", "--world", "box", "--out", "x"}, dir);
  EXPECT_NE(range.status, 0);
  EXPECT_NE(range.err.find("--duration"), std::string::npos) << range.err;
  EXPECT_EQ(range.err.find("unknown option"), std::string::npos) << range.err;
}

// --- built-in worlds -------------------------------------------------------------------------

void ExpectEveryBuiltinWorld(const std::string& text, const std::string& what) {
  const std::vector<std::string> names = sim::BuiltinWorldNames();
  ASSERT_GE(names.size(), 9u);
  for (const std::string& name : names) {
    EXPECT_NE(text.find(name), std::string::npos) << what << " lacks " << name << ":\n" << text;
  }
  EXPECT_NE(text.find(sim::BuiltinWorldList()), std::string::npos) << what << ":\n" << text;
}

TEST(BuiltinWorldsTest, TheListComesFromTheTableAndEveryNameResolves) {
  const std::vector<std::string> names = sim::BuiltinWorldNames();
  EXPECT_EQ(std::set<std::string>(names.begin(), names.end()).size(), names.size());
  std::string joined;
  for (const std::string& name : names) {
    joined += (joined.empty() ? "" : ", ") + name;
    const Result<sim::World> world = sim::ResolveWorld(name);
    ASSERT_TRUE(world.ok()) << name << ": " << world.Message();
  }
  EXPECT_EQ(sim::BuiltinWorldList(), joined);
}

TEST(BuiltinWorldsTest, AnUnknownWorldListsEveryBuiltinOne) {
  const Result<sim::World> kitchen = sim::ResolveWorld("kitchen");
  ASSERT_FALSE(kitchen.ok());
  EXPECT_NE(kitchen.Message().find("'kitchen'"), std::string::npos) << kitchen.Message();
  EXPECT_NE(kitchen.Message().find("No such file or directory"), std::string::npos);
  ExpectEveryBuiltinWorld(kitchen.Message(), "ResolveWorld");

  const fs::path dir = Scratch("worlds");
  const ToolRun sim = RunTool({SLAM_SIM_BIN, "--world", "kitchen", "--out", "exp"}, dir);
  EXPECT_EQ(sim.status, 1);
  ExpectEveryBuiltinWorld(sim.err, "slam-sim --world kitchen");
  EXPECT_FALSE(fs::exists(dir / "exp"));

  const ToolRun slamd = RunTool({SLAMD_BIN, "--source", "sim:kitchen", "--port", "0"}, dir);
  EXPECT_NE(slamd.status, 0);
  EXPECT_NE(slamd.err.find("sim:kitchen"), std::string::npos) << slamd.err;
  ExpectEveryBuiltinWorld(slamd.err, "slamd --source sim:kitchen");

  const ToolRun link = RunTool({SLAM_LINK_BIN, "--source", "sim:kitchen", "--seconds", "1"}, dir);
  EXPECT_NE(link.status, 0);
  ExpectEveryBuiltinWorld(link.err, "slam-link --source sim:kitchen");

  // A file that exists but is not a world is still reported as that file's problem.
  std::ofstream(dir / "broken.json") << "{";
  const ToolRun broken = RunTool({SLAM_SIM_BIN, "--world", "broken.json", "--out", "exp"}, dir);
  EXPECT_EQ(broken.status, 1);
  EXPECT_NE(broken.err.find("broken.json"), std::string::npos) << broken.err;
  EXPECT_EQ(broken.err.find("neither a built-in world"), std::string::npos) << broken.err;
}

TEST(BuiltinWorldsTest, EveryHelpThatTakesAWorldListsEveryBuiltinOne) {
  const fs::path dir = Scratch("help");
  for (const char* binary : {SLAM_SIM_BIN, SLAMD_BIN, SLAM_LINK_BIN}) {
    const ToolRun help = RunTool({binary, "--help"}, dir);
    EXPECT_EQ(help.status, 0) << binary;
    // CLI11 may wrap a long description: compare with the whitespace squeezed.
    const std::string squeezed = std::regex_replace(help.out, std::regex("\\s+"), " ");
    ExpectEveryBuiltinWorld(squeezed, std::string(binary) + " --help");
  }
}

// Every option slamd's --help lists is in docs/http-api.md's "Starting slamd" synopsis or text.
TEST(DocsTest, EverySlamdOptionIsInTheApiDocument) {
  const fs::path dir = Scratch("slamd-options");
  const ToolRun help = RunTool({SLAMD_BIN, "--help"}, dir);
  ASSERT_EQ(help.status, 0);
  const std::string whole = ReadAll(fs::path(SLAM_SOURCE_DIR) / "docs/http-api.md");
  const size_t from = whole.find("## Starting slamd"), to = whole.find("\n## ", from + 1);
  ASSERT_NE(from, std::string::npos);
  const std::string doc = whole.substr(from, to - from);  // that section only
  // CLI11 lists each option at the start of a line: "  --port INT ...", "  -h,--help ...".
  const std::regex option(R"((?:^|\n)\s+(?:-[A-Za-z],)?(--[a-z][a-z0-9-]*))");
  int options = 0;
  for (std::sregex_iterator m(help.out.begin(), help.out.end(), option), end; m != end; ++m) {
    const std::string name = (*m)[1].str();
    ++options;
    const std::regex named(name + "(?![a-z0-9-])");
    EXPECT_TRUE(std::regex_search(doc, named))
        << name << " is not in docs/http-api.md's Starting slamd";
  }
  EXPECT_GE(options, 20);
}

// --- slam-evaluate --params DIR of a study of some budgets -----------------------------------

TEST(EvaluateParamsTest, ADirectoryKeepsTheShippedSetForTheBudgetsItLacks) {
  const fs::path dir = Scratch("params-dir");
  // A study that tuned 65000 only (here: the shipped 8125 set, so that it differs from 65000's).
  fs::create_directories(dir / "tune" / "params");
  fs::copy_file(fs::path(SLAM_SOURCE_DIR) / "config/params/8125.json",
                dir / "tune/params/65000.json");
  const auto found = offline::LoadParamsDirectory((dir / "tune/params").string(), {8125, 65000});
  ASSERT_TRUE(found.ok()) << found.Message();
  EXPECT_EQ(found.value().shipped, std::vector<int64_t>{8125});
  ASSERT_EQ(found.value().by_budget.size(), 1u);
  EXPECT_EQ(found.value().by_budget.count(65000), 1u);

  // A file that is there but broken is an error naming it, never replaced by the shipped set.
  std::ofstream(dir / "tune/params/8125.json") << "{\"sigma_xy\": ";
  const auto broken = offline::LoadParamsDirectory((dir / "tune/params").string(), {8125, 65000});
  ASSERT_FALSE(broken.ok());
  EXPECT_NE(broken.Message().find("8125.json"), std::string::npos) << broken.Message();
  fs::remove(dir / "tune/params/8125.json");
  EXPECT_FALSE(offline::LoadParamsDirectory((dir / "nowhere").string(), {8125}).ok());

  // The tool, end to end on a short simulated experiment.
  const ToolRun sim =
      RunTool({SLAM_SIM_BIN, "--world", "box", "--duration", "8", "--out", "exp"}, dir);
  ASSERT_EQ(sim.status, 0) << sim.err;
  const ToolRun evaluate =
      RunTool({SLAM_EVALUATE_BIN, "exp", "--out", "results", "--budgets", "8125,65000", "--modes",
               "slam", "--params", "tune/params", "--jobs", "1"},
              dir);
  ASSERT_EQ(evaluate.status, 0) << evaluate.err;
  EXPECT_NE(evaluate.err.find("slam-evaluate: tune/params has no 8125.json: budget 8125 uses the "
                              "shipped set"),
            std::string::npos)
      << evaluate.err;
  EXPECT_EQ(evaluate.err.find("65000.json:"), std::string::npos) << evaluate.err;
  const Json runs = Json::parse(ReadAll(dir / "results/runs.json"));
  ASSERT_EQ(runs.size(), 2u);
  const auto shipped_8125 = io::LoadParams(SLAM_SOURCE_DIR "/config/params/8125.json");
  ASSERT_TRUE(shipped_8125.ok());
  for (const Json& run : runs) {
    // Both budgets ran the 8125 set: 8125 its shipped one, 65000 the study's copy of it.
    EXPECT_EQ(run["params"], io::ParamsToJson(shipped_8125.value())) << run["budget"];
  }
}

// --- generations numbered from 1 -------------------------------------------------------------

TEST(TuningNumbersTest, Table3NumbersGenerationsFromOneAsTheConsoleDoes) {
  offline::TuningState state;
  for (const int64_t budget : {8125, 65000}) {
    offline::BudgetRun run;
    run.budget = budget;
    for (int g = 0; g < 3; ++g) {
      offline::GenerationSummary summary;
      summary.generation = g;  // 0-based inside, as results.json keeps it
      summary.fitness_values = {-1.0 - g, -2.0 - g, -1.5 - g, -0.5 * static_cast<double>(budget)};
      summary.fitness.median = -1.5 - g;
      run.generations.push_back(summary);
    }
    state.budgets.push_back(run);
  }
  const std::string md = offline::Table3Markdown(state);
  EXPECT_NE(md.find("8125 at generation 3 ("), std::string::npos) << md;
  EXPECT_NE(md.find("65000 at generation 3 ("), std::string::npos) << md;
  EXPECT_EQ(md.find("at generation 2 ("), std::string::npos) << md;
}

// --- slam-relations says why ------------------------------------------------------------------

TEST(RelationsToolTest, AFileThatCannotBeReadIsNamedWithTheReason) {
  const fs::path dir = Scratch("relations");
  std::ofstream(dir / "r.relations") << "0 1 0.1 0 0 0 0 0\n";
  std::ofstream(dir / "good.tum") << "0 0 0 0 0 0 0 1\n1 0.1 0 0 0 0 0 1\n";
  std::ofstream(dir / "bad.tum") << "0 0 0 0 0 0 0 1\n1 0.1 0 0\n";
  fs::create_directories(dir / "folder.tum");
  const std::string tool = SLAM_RELATIONS_BIN;
  const ToolRun good = RunTool({tool, "--relations", "r.relations", "good.tum"}, dir);
  ASSERT_EQ(good.status, 0) << good.err;

  const ToolRun missing = RunTool({tool, "--relations", "r.relations", "missing.tum"}, dir);
  EXPECT_EQ(missing.status, 1);
  EXPECT_NE(missing.err.find("missing.tum"), std::string::npos) << missing.err;
  EXPECT_NE(missing.err.find("No such file or directory"), std::string::npos) << missing.err;

  const ToolRun folder = RunTool({tool, "--relations", "r.relations", "folder.tum"}, dir);
  EXPECT_EQ(folder.status, 1);
  EXPECT_NE(folder.err.find("folder.tum: is a directory"), std::string::npos) << folder.err;

  const ToolRun bad = RunTool({tool, "--relations", "r.relations", "good.tum", "bad.tum"}, dir);
  EXPECT_EQ(bad.status, 1);
  EXPECT_NE(bad.err.find("bad.tum:2:"), std::string::npos) << bad.err;
  EXPECT_NE(bad.err.find("found 4"), std::string::npos) << bad.err;

  const ToolRun no_relations = RunTool({tool, "--relations", "none.relations", "good.tum"}, dir);
  EXPECT_EQ(no_relations.status, 1);
  EXPECT_NE(no_relations.err.find("none.relations"), std::string::npos) << no_relations.err;
  EXPECT_NE(no_relations.err.find("No such file or directory"), std::string::npos)
      << no_relations.err;
}

// --- the README's outputs are ignored ---------------------------------------------------------

TEST(GitIgnoreTest, EveryOutputTheReadmeWritesIsIgnored) {
  const fs::path source = SLAM_SOURCE_DIR;
  if (!fs::exists(source / ".git")) GTEST_SKIP() << "not a git checkout";
  if (std::system("git --version >/dev/null 2>&1") != 0) GTEST_SKIP() << "no git";
  // Where the README's examples write, relative to the checkout: each `--out DIR` in them,
  // slam-replay's default ("files in replay-rooms-2/"), and each script's default OUT.
  std::set<std::string> outputs;
  const std::string readme = ReadAll(source / "README.md");
  const std::regex out_option(R"(--out ([A-Za-z0-9_.][A-Za-z0-9_./-]*))");
  for (std::sregex_iterator m(readme.begin(), readme.end(), out_option), end; m != end; ++m) {
    outputs.insert(fs::path((*m)[1].str()).begin()->string());
  }
  const std::regex files_in(R"(files in ([A-Za-z0-9_.-]+)/)");
  for (std::sregex_iterator m(readme.begin(), readme.end(), files_in), end; m != end; ++m) {
    outputs.insert((*m)[1].str());
  }
  for (const auto& script : fs::directory_iterator(source / "scripts")) {
    if (!script.is_regular_file()) continue;
    const std::string text = ReadAll(script.path());
    const std::regex default_out(R"(OUT defaults to ([A-Za-z0-9_.-]+))");
    for (std::sregex_iterator m(text.begin(), text.end(), default_out), end; m != end; ++m) {
      outputs.insert((*m)[1].str());
    }
  }
  outputs.insert("build-cli");  // a build directory of one's own
  for (const char* expected : {"exp", "results", "tune", "replay-rooms-2"}) {
    EXPECT_EQ(outputs.count(expected), 1u) << expected << " not found in the README";
  }
  for (const std::string& output : outputs) {
    const std::string command =
        "git -C '" + source.string() + "' check-ignore -q --no-index '" + output + "/file'";
    EXPECT_EQ(std::system(command.c_str()), 0) << output << "/ is not in .gitignore";
  }
}

}  // namespace
}  // namespace slam
