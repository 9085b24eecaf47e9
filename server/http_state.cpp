#include "server/http_state.hpp"

#include <cstdio>
#include <filesystem>
#include <set>

#include "engine/io/map_image.hpp"
#include "server/api_json.hpp"

namespace slam::server {

Result<std::string> TileCache::Png(int32_t x, int32_t y, uint64_t version, const Tile& tile) {
  {
    MutexLock lock(mutex_);
    const auto cached = cache_.find({x, y});
    if (cached != cache_.end() && cached->second.first == version) return cached->second.second;
  }
  const Result<io::PngBytes> bytes = io::EncodeGrayPng(kTileSize, kTileSize, io::TileGray(tile));
  if (!bytes.ok()) return bytes.errors();
  std::string png(bytes.value().begin(), bytes.value().end());
  MutexLock lock(mutex_);
  cache_[{x, y}] = {version, png};
  return png;
}

ExportCache::ExportCache(SlamService& service, std::initializer_list<const char*> kinds)
    : service_(service) {
  for (const char* kind : kinds) entries_.try_emplace(kind);
}

void ExportCache::Serve(const std::string& kind, const Make& make, httplib::Response& res) {
  Entry& e = entries_.at(kind);
  MutexLock lock(e.mutex);
  const auto snapshot = service_.Snapshot();
  if (!e.valid || e.sequence != snapshot->sequence) {
    e.valid = false;
    std::string error;
    if (!make(*snapshot, e.body, e.type, error)) {
      SendProblem(res, 500, "Internal Server Error", error);
      return;
    }
    e.valid = true;
    e.sequence = snapshot->sequence;
    e.renders.fetch_add(1);
  }
  res.set_content(e.body, e.type.c_str());
}

std::map<std::string, uint64_t> ExportCache::Made() const {
  std::map<std::string, uint64_t> made;
  for (const auto& [kind, e] : entries_) made[kind] = e.renders.load();
  return made;
}

Result<nlohmann::json> SaveCoordinator::SaveFor(Clock::time_point arrived) {
  MutexLock lock(mutex_);
  if (last_.valid && last_.started >= arrived) return last_.answer;
  const Result<SaveReport> saved = SaveLocked();
  if (!saved.ok()) return saved.errors();
  return last_.answer;
}

Result<SaveReport> SaveCoordinator::SaveNow() {
  if (!enabled()) return Error("slamd was started without --state-dir");
  MutexLock lock(mutex_);
  return SaveLocked();
}

Result<SaveReport> SaveCoordinator::SaveLocked() {
  last_.valid = false;
  last_.started = Clock::now();
  const auto snapshot = service_.Snapshot();
  const OccupancyGrid grid = SnapshotGrid(*snapshot, service_.encoded_logodds_limit());
  SaveInputs in;
  in.version = snapshot->map_version;
  in.resolution_m = snapshot->resolution_m;
  in.grid = &grid;
  in.version_base = snapshot->version_base;
  in.trajectory = ScanEndTrajectory(*snapshot);
  Result<SaveReport> saved = SaveState(state_dir_, in);
  if (!saved.ok()) return saved;
  saves_made_.fetch_add(1);
  last_.answer = {{"path", std::filesystem::absolute(state_dir_).string()},
                  {"version", snapshot->map_version},
                  {"tiles", snapshot->tiles.size()},
                  {"warnings", saved.value().warnings}};
  for (const std::string& warning : saved.value().warnings) {
    std::fprintf(stderr, "slamd: map saved, but a copy was not written: %s\n", warning.c_str());
  }
  last_.valid = true;
  return saved;
}

void RequestCounter::Count(const std::string& method, int status) {
  static const std::set<std::string> kMethods{"GET",    "HEAD",    "POST",  "PUT",    "PATCH",
                                              "DELETE", "OPTIONS", "TRACE", "CONNECT"};
  const std::string label = kMethods.count(method) ? method : "other";
  MutexLock lock(mutex_);
  ++counts_[{label, status}];
}

std::map<std::pair<std::string, int>, uint64_t> RequestCounter::Counts() const {
  MutexLock lock(mutex_);
  return counts_;
}

}  // namespace slam::server
