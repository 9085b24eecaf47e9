// slamd over HTTP, as a black box (docs/http-api.md): tuning jobs on two small generated
// experiments. The harness and its conventions are slamd_http_test.cpp's
// (tests/slamd_harness.hpp).

#include <signal.h>

#include <algorithm>
#include <cstdlib>
#include <limits>
#include <sstream>

#include "engine/quality.hpp"
#include "tests/slamd_harness.hpp"

namespace slamd_test {
namespace {

// ---------------------------------------------------------------------------------------------
// Tuning jobs on two small generated experiments

class JobsSlamd : public SlamdSuite {
 protected:
  static void SetUpTestSuite() {
    experiments_ = std::make_unique<ScratchDir>("experiments");
    for (const auto& [name, seed] : {std::pair<std::string, int>{"box-1", 1}, {"box-2", 2}}) {
      const std::string command = SlamSimBinary() + " --world box --duration 10 --seed " +
                                  std::to_string(seed) + " --out " +
                                  (experiments_->path() / name).string() + " > /dev/null";
      if (std::system(command.c_str()) != 0) {
        start_error_ = "failed: " + command;
        slamd_ = std::make_unique<SlamdProcess>();
        return;
      }
    }
    StartShared({"--experiments", experiments_->path().string(), "--budget", "8000"});
  }
  static void TearDownTestSuite() {
    StopShared();
    experiments_.reset();
  }

  /// Polls GET /api/v1/jobs/{id} until `done` holds; the last job object.
  template <typename Predicate>
  json PollJob(const std::string& id, double timeout_s, Predicate done) {
    const auto deadline = After(timeout_s);
    json job;
    while (true) {
      job = GetJson(http(), "/api/v1/jobs/" + id);
      if (done(job) || Clock::now() >= deadline) return job;
      std::this_thread::sleep_for(std::chrono::milliseconds(100));
    }
  }

  static inline std::unique_ptr<ScratchDir> experiments_;
};

void ExpectJobShape(const json& job) {
  for (const char* key : {"id", "state", "policy", "error"}) {
    EXPECT_TRUE(job[key].is_string()) << key << " in " << job.dump();
  }
  for (const char* key : {"budget", "population", "generations", "generation", "evaluations_done",
                          "evaluations_total"}) {
    EXPECT_TRUE(job[key].is_number_integer()) << key << " in " << job.dump();
  }
  EXPECT_TRUE(job["progress"].is_number()) << job.dump();
  EXPECT_GE(job.value("progress", -1.0), 0.0);
  EXPECT_LE(job.value("progress", 2.0), 1.0);
  EXPECT_TRUE(job["experiments"].is_array()) << job.dump();
  EXPECT_TRUE(job["history"].is_array()) << job.dump();
  EXPECT_TRUE(job.contains("best")) << job.dump();
}

TEST_F(JobsSlamd, BadTuneBodiesAre422Or400Or415) {
  Expect422At(http().PostJson("/api/v1/jobs/tune", R"({"population": 0})"), {"/population"});
  Expect422At(http().PostJson("/api/v1/jobs/tune", R"({"generations": "x"})"), {"/generations"});
  Expect422At(http().PostJson("/api/v1/jobs/tune", R"({"policy": "lazy"})"), {"/policy"});
  Expect422At(http().PostJson("/api/v1/jobs/tune", R"({"budget": -5})"), {"/budget"});
  Expect422At(http().PostJson("/api/v1/jobs/tune", R"({"bogus": 1})"), {"/bogus"});
  Expect422At(http().PostJson("/api/v1/jobs/tune", R"({"experiments": ["no-such-experiment"]})"),
              {"/experiments/0"});
  Expect422At(http().PostJson("/api/v1/jobs/tune", R"({"experiments": "box-1"})"),
              {"/experiments"});
  // A name repeated would load that experiment again for each copy.
  Expect422At(
      http().PostJson("/api/v1/jobs/tune", R"({"experiments": ["box-1", "box-2", "box-1"]})"),
      {"/experiments/2"});
  Expect422At(http().PostJson("/api/v1/jobs/tune", R"({"population": 0, "seed": "s"})"),
              {"/population", "/seed"});
  Expect422At(http().PostJson("/api/v1/jobs/tune", "[]"), {""});
  ExpectProblem(http().PostJson("/api/v1/jobs/tune", "{"), 400);
  ExpectProblem(http().Send("POST", "/api/v1/jobs/tune", "{}", "text/plain"), 415);
  // None of them started a job.
  const json jobs = GetJson(http(), "/api/v1/jobs");
  ASSERT_TRUE(jobs["jobs"].is_array());
  for (const auto& job : jobs["jobs"]) EXPECT_NE(job.value("state", ""), "running") << job.dump();
}

TEST_F(JobsSlamd, SecondJobIs409AndDeleteCancelsThenForgets) {
  const Reply started = http().PostJson(
      "/api/v1/jobs/tune", R"({"population": 12, "generations": 8, "budget": 2000, "seed": 3})");
  ASSERT_EQ(started.status, 202) << started;
  const json job = started.Json();
  ExpectJobShape(job);
  const std::string id = job.value("id", "");
  ASSERT_FALSE(id.empty());
  EXPECT_EQ(job.value("state", ""), "running");
  EXPECT_EQ(job.value("population", 0), 12);
  EXPECT_EQ(job.value("generations", 0), 8);
  EXPECT_EQ(job.value("budget", 0), 2000);
  EXPECT_EQ(job["experiments"], json({"box-1", "box-2"}));

  ExpectProblem(http().PostJson("/api/v1/jobs/tune", "{}"), 409);
  const json status = GetJson(http(), "/api/v1/status");
  ASSERT_TRUE(status["job"].is_object()) << status.dump();
  EXPECT_EQ(status["job"].value("id", ""), id);
  EXPECT_EQ(Metric(GetMetrics(http()), "slamd_jobs_running"), 1.0);
  const json listed = GetJson(http(), "/api/v1/jobs");
  ASSERT_TRUE(listed["jobs"].is_array());
  bool found = false;
  for (const auto& entry : listed["jobs"]) found = found || entry.value("id", "") == id;
  EXPECT_TRUE(found) << listed.dump();

  const Reply cancel = http().Send("DELETE", "/api/v1/jobs/" + id, "", "");
  EXPECT_EQ(cancel.status, 202) << cancel;
  const json cancelled =
      PollJob(id, 15.0, [](const json& j) { return j.value("state", "") != "running"; });
  EXPECT_EQ(cancelled.value("state", ""), "cancelled") << cancelled.dump();
  EXPECT_LT(cancelled.value("evaluations_done", 1 << 30), cancelled.value("evaluations_total", 0));
  EXPECT_EQ(PollMetric(http(), "slamd_jobs_running", 3.0, [](double v) { return v == 0.0; }), 0.0);

  const Reply forget = http().Send("DELETE", "/api/v1/jobs/" + id, "", "");
  EXPECT_EQ(forget.status, 200) << forget;
  ExpectProblem(http().Get("/api/v1/jobs/" + id), 404);
  ExpectProblem(http().Send("DELETE", "/api/v1/jobs/" + id, "", ""), 404);
}

TEST_F(JobsSlamd, SmallJobReportsProgressAndFinishes) {
  // Make sure no job of another test is still running.
  const json jobs = GetJson(http(), "/api/v1/jobs");
  for (const auto& job : jobs["jobs"]) {
    if (job.value("state", "") == "running") {
      http().Send("DELETE", "/api/v1/jobs/" + job.value("id", ""), "", "");
      PollJob(job.value("id", ""), 15.0,
              [](const json& j) { return j.value("state", "") != "running"; });
    }
  }
  EventStream stream;
  ASSERT_EQ(stream.Open(port()), 200);
  ASSERT_TRUE(stream.WaitFor("hello", 5.0).has_value());

  const Reply started = http().PostJson(
      "/api/v1/jobs/tune", R"({"population": 2, "generations": 1, "budget": 2000, "seed": 1,)"
                           R"( "experiments": ["box-1"]})");
  ASSERT_EQ(started.status, 202) << started;
  const std::string id = started.Json().value("id", "");
  ASSERT_FALSE(id.empty());
  EXPECT_EQ(started.Json()["experiments"], json({"box-1"}));

  int64_t last_done = 0;
  double last_progress = 0.0;
  const json finished = PollJob(id, 40.0, [&](const json& j) {
    const int64_t done = j.value("evaluations_done", int64_t{0});
    const double progress = j.value("progress", 0.0);
    EXPECT_GE(done, last_done) << "evaluations_done went back";
    EXPECT_GE(progress, last_progress) << "progress went back";
    last_done = done;
    last_progress = progress;
    return j.value("state", "") != "running";
  });
  ExpectJobShape(finished);
  ASSERT_EQ(finished.value("state", ""), "done") << finished.dump();
  EXPECT_EQ(finished.value("error", "?"), "");
  EXPECT_GT(finished.value("evaluations_total", 0), 0);
  EXPECT_EQ(finished.value("evaluations_done", 0), finished.value("evaluations_total", -1));
  EXPECT_DOUBLE_EQ(finished.value("progress", 0.0), 1.0);
  ASSERT_FALSE(finished["history"].empty());
  int number = 0;
  for (const auto& generation : finished["history"]) {
    // Numbered 1..N, as slam-tune's console, table3.md and Fig. 10 number them.
    EXPECT_EQ(generation.value("generation", -1), ++number) << generation.dump();
    for (const char* key : {"min", "q1", "median", "q3", "max"}) {
      EXPECT_TRUE(generation[key].is_number()) << key << " in " << generation.dump();
    }
    EXPECT_LE(generation.value("min", 1.0), generation.value("median", 0.0));
    EXPECT_LE(generation.value("median", 1.0), generation.value("max", 0.0));
  }
  ASSERT_TRUE(finished["best"].is_object()) << finished.dump();
  EXPECT_TRUE(finished["best"]["fitness"].is_number());
  EXPECT_TRUE(finished["best"]["params"].is_object());

  // The stream announced the job, finally as done.
  bool saw_done = false;
  const auto deadline = After(5.0);
  while (!saw_done && Clock::now() < deadline) {
    const auto event =
        stream.WaitFor("job", std::chrono::duration<double>(deadline - Clock::now()).count());
    if (!event) break;
    EXPECT_EQ(event->Json().value("id", ""), id);
    saw_done = event->Json().value("state", "") == "done";
  }
  EXPECT_TRUE(saw_done);

  // A finished job can be forgotten.
  EXPECT_EQ(http().Send("DELETE", "/api/v1/jobs/" + id, "", "").status, 200);
  ExpectProblem(http().Get("/api/v1/jobs/" + id), 404);
}

TEST_F(JobsSlamd, JobIdsGoOnFromAnEarlierRunsResults) {
  // Results of an earlier run's jobs stay in --state-dir/jobs/<id>/: a new job must not take
  // one of their ids (it would write over their results).
  ScratchDir state("jobs_state");
  fs::create_directories(state.path() / "jobs" / "1");
  fs::create_directories(state.path() / "jobs" / "7");
  fs::create_directories(state.path() / "jobs" / "notes");
  WriteFile(state.path() / "jobs" / "7" / "results.json", "{\"earlier\": true}\n");
  SlamdProcess slamd;
  std::string error;
  ASSERT_TRUE(slamd.Start({"--experiments", experiments_->path().string(), "--state-dir",
                           state.path().string(), "--budget", "8000"},
                          &error))
      << error;
  Http own(slamd.host(), slamd.port());
  const Reply started = own.PostJson(
      "/api/v1/jobs/tune",
      R"({"population": 2, "generations": 1, "budget": 2000, "experiments": ["box-1"]})");
  ASSERT_EQ(started.status, 202) << started;
  const std::string id = started.Json().value("id", "");
  EXPECT_EQ(id, "8");
  own.Send("DELETE", "/api/v1/jobs/" + id, "", "");
  EXPECT_EQ(ReadFile(state.path() / "jobs" / "7" / "results.json"), "{\"earlier\": true}\n");
}

TEST_F(JobsSlamd, OnlyTheSixteenNewestJobsAreKept) {
  // A client starting job after job (each cancelled at once) must not grow slamd without bound:
  // slamd keeps the 16 newest, oldest listed first. A job that finished before its DELETE
  // arrived is deleted by it (200 instead of 202: it happens on a loaded machine), so the jobs
  // left to keep are those whose DELETE cancelled them.
  constexpr int kStarted = 21;
  constexpr size_t kKept = 16;
  std::vector<std::string> ids, cancelled;
  for (int i = 0; i < kStarted; ++i) {
    const Reply started = http().PostJson(
        "/api/v1/jobs/tune",
        R"({"population": 2, "generations": 1, "budget": 2000, "experiments": ["box-1"]})");
    ASSERT_EQ(started.status, 202) << "job " << i << ": " << started;
    ids.push_back(started.Json().value("id", ""));
    ASSERT_FALSE(ids.back().empty());
    const Reply deleted = http().Send("DELETE", "/api/v1/jobs/" + ids.back(), "", "");
    ASSERT_TRUE(deleted.status == 202 || deleted.status == 200) << deleted;
    if (deleted.status == 202) {
      cancelled.push_back(ids.back());
      const json job = PollJob(ids.back(), 15.0,
                               [](const json& j) { return j.value("state", "") != "running"; });
      ASSERT_NE(job.value("state", ""), "running") << job.dump();
    }
  }
  ASSERT_GT(cancelled.size(), kKept) << "too few jobs were still running when cancelled";
  const json listed = GetJson(http(), "/api/v1/jobs");
  ASSERT_TRUE(listed["jobs"].is_array()) << listed.dump();
  std::vector<std::string> kept;
  for (const auto& job : listed["jobs"]) kept.push_back(job.value("id", ""));
  const std::vector<std::string> newest(cancelled.end() - kKept, cancelled.end());
  EXPECT_EQ(kept, newest);
  for (const std::string& id : ids) {
    if (std::find(newest.begin(), newest.end(), id) == newest.end()) {
      ExpectProblem(http().Get("/api/v1/jobs/" + id), 404);
    }
  }
  EXPECT_EQ(GetJson(http(), "/api/v1/jobs/" + newest.back()).value("id", ""), newest.back());
  // The latest job still kept is the status's job, unless the very last was deleted.
  const json status = GetJson(http(), "/api/v1/status");
  if (newest.back() == ids.back()) {
    ASSERT_TRUE(status["job"].is_object()) << status.dump();
    EXPECT_EQ(status["job"].value("id", ""), ids.back());
  }
}

}  // namespace
}  // namespace slamd_test
