#pragma once
// Progress figures for the HUD: how fast a count grows towards its total,
// how long the rest will take, and the text that says so with its units.
//
// Threads: render thread (plain values; no locking).

#include <chrono>
#include <cstdint>
#include <optional>
#include <string>

namespace penumbra::client {

/// The rate of a count that grows towards a total (samples of a view), as a
/// moving average over about `window`, and the time left at that rate. A
/// count that goes down (a new view restarts its counts) starts over.
class ProgressRate {
 public:
  using Clock = std::chrono::steady_clock;
  explicit ProgressRate(std::chrono::milliseconds window = std::chrono::milliseconds(2000)) : window_(window) {}

  void Update(uint64_t done, uint64_t total, Clock::time_point now);
  /// Per second; nullopt until two updates a measurable time apart.
  std::optional<double> PerSecond() const { return rate_; }
  /// At the current rate; nullopt without a rate (or with a zero rate).
  std::optional<std::chrono::seconds> TimeLeft() const;

 private:
  std::chrono::milliseconds window_;
  std::optional<Clock::time_point> last_;
  uint64_t lastDone_ = 0;
  uint64_t total_ = 0;
  uint64_t done_ = 0;
  std::optional<double> rate_;
};

/// "12,345".
std::string FormatCount(uint64_t n);
/// "45 s", "2 min 05 s", "1 h 03 min".
std::string FormatDuration(std::chrono::seconds d);
/// "850 B/s", "12.3 kB/s", "1.5 MB/s".
std::string FormatBytesPerSecond(double bytesPerSecond);

}  // namespace penumbra::client
