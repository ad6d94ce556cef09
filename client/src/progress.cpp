#include "penumbra/client/progress.h"

#include <algorithm>
#include <cmath>

#include <fmt/format.h>

namespace penumbra::client {

void ProgressRate::Update(uint64_t done, uint64_t total, Clock::time_point now) {
  if (!last_ || done < lastDone_) {
    // First call, or the count restarted (a new view): no rate yet.
    last_ = now;
    lastDone_ = done_ = done;
    total_ = total;
    rate_.reset();
    return;
  }
  total_ = total;
  done_ = done;
  const double seconds = std::chrono::duration<double>(now - *last_).count();
  // Too short an interval measures the frame rate, not the samples'.
  if (seconds < 0.25) return;
  const double instant = double(done - lastDone_) / seconds;
  const double a = 1.0 - std::exp(-seconds / std::chrono::duration<double>(window_).count());
  rate_ = rate_ ? *rate_ + a * (instant - *rate_) : instant;
  last_ = now;
  lastDone_ = done;
}

std::optional<std::chrono::seconds> ProgressRate::TimeLeft() const {
  if (!rate_ || *rate_ <= 0.0 || done_ >= total_) return std::nullopt;
  const double seconds = double(total_ - done_) / *rate_;
  if (!std::isfinite(seconds) || seconds > 1e7) return std::nullopt;
  return std::chrono::seconds(int64_t(std::ceil(seconds)));
}

std::string FormatCount(uint64_t n) {
  std::string digits = std::to_string(n);
  std::string out;
  for (size_t i = 0; i < digits.size(); ++i) {
    if (i > 0 && (digits.size() - i) % 3 == 0) out += ',';
    out += digits[i];
  }
  return out;
}

std::string FormatDuration(std::chrono::seconds d) {
  const int64_t s = std::max<int64_t>(0, d.count());
  if (s < 60) return fmt::format("{} s", s);
  if (s < 3600) return fmt::format("{} min {:02} s", s / 60, s % 60);
  return fmt::format("{} h {:02} min", s / 3600, (s % 3600) / 60);
}

std::string FormatBytesPerSecond(double bytesPerSecond) {
  if (bytesPerSecond >= 1e6) return fmt::format("{:.1f} MB/s", bytesPerSecond / 1e6);
  if (bytesPerSecond >= 1e3) return fmt::format("{:.1f} kB/s", bytesPerSecond / 1e3);
  return fmt::format("{:.0f} B/s", bytesPerSecond);
}

}  // namespace penumbra::client
