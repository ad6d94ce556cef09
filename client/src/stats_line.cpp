#include "penumbra/client/stats_line.h"

#include <cstring>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

namespace penumbra::client {

ProcessMemory ReadProcessMemory() {
  ProcessMemory memory;
  std::ifstream in("/proc/self/status");
  std::string line;
  // Lines look like "VmRSS:	   12345 kB".
  auto kilobytes = [](const std::string& l) { return uint64_t(std::strtoull(l.c_str() + l.find(':') + 1, nullptr, 10)); };
  while (std::getline(in, line)) {
    if (line.starts_with("VmRSS:")) memory.residentBytes = kilobytes(line) * 1024;
    if (line.starts_with("VmHWM:")) memory.peakResidentBytes = kilobytes(line) * 1024;
  }
  return memory;
}

std::string FormatStatsLine(const FrameStats& s) {
  nlohmann::json j;
  j["frame"] = s.frame;
  j["time_s"] = s.timeSeconds;
  j["triangles_held"] = s.trianglesHeld;
  j["vertices_held"] = s.verticesHeld;
  j["bytes_received"] = s.bytesReceived;
  j["samples_pending"] = s.samplesPending;
  j["converged"] = s.converged;
  j["refining"] = s.refining;
  j["triangles_added"] = s.trianglesAdded;
  j["view_to_first_delta_ms"] = s.viewToFirstDeltaMs ? nlohmann::json(*s.viewToFirstDeltaMs) : nlohmann::json();
  j["fps"] = s.fps;
  j["rss_bytes"] = s.memory.residentBytes;
  j["peak_rss_bytes"] = s.memory.peakResidentBytes;
  j["connection"] = s.connection;
  j["connections"] = s.connections;
  j["sma_triangles_held"] = s.sma ? nlohmann::json(s.sma->trianglesHeld) : nlohmann::json();
  j["sma_vertices_held"] = s.sma ? nlohmann::json(s.sma->verticesHeld) : nlohmann::json();
  j["sma_agrees"] = s.sma ? nlohmann::json(s.sma->agrees) : nlohmann::json();
  j["scene_epoch"] = s.sceneEpoch;
  j["moves_sent"] = s.movesSent;
  j["moves_pending"] = s.movesPending;
  return j.dump();
}

Expected<StatsLineWriter> StatsLineWriter::Open(const std::filesystem::path& path) {
  std::ofstream out(path, std::ios::trunc);
  if (!out) return Fail(fmt::format("{}: cannot create the statistics file: {}", path.string(), std::strerror(errno)));
  return StatsLineWriter(std::move(out), path);
}

Status StatsLineWriter::Write(const FrameStats& stats) {
  out_ << FormatStatsLine(stats) << '\n';
  out_.flush();
  if (!out_) return Fail(fmt::format("{}: cannot write the statistics line", path_.string()));
  return Status::Ok();
}

}  // namespace penumbra::client
