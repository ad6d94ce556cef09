#pragma once
// Metrics for operators: a lock-free histogram, a writer and a strict parser
// of the Prometheus text exposition format (version 0.0.4), and the
// process's resident memory. The HTTP side is operator_http.h; the metric
// names each tier exports are listed in docs/metrics.md.
//
// Threads: Histogram::Observe and Histogram::Read may be called from any
// thread at once (atomics only, no lock). ExpositionWriter and the parser are
// plain values used by one thread.

#include <atomic>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "penumbra/common/expected.h"

namespace penumbra::metrics {

using Labels = std::vector<std::pair<std::string, std::string>>;

/// A Prometheus histogram: counts of observations at or below fixed upper
/// bounds, their number and their sum. Observe is wait-free, so I/O threads
/// and strands record into it without contention; Read gives a snapshot that
/// is consistent enough for monitoring (buckets, count and sum are read one
/// after another, not atomically together).
class Histogram {
 public:
  /// `upperBounds`: strictly increasing, finite; +Inf is implied.
  explicit Histogram(std::vector<double> upperBounds);

  void Observe(double value);

  struct Snapshot {
    std::vector<double> upperBounds;     // without +Inf
    std::vector<uint64_t> cumulative;    // one per bound, then +Inf (== count)
    uint64_t count = 0;
    double sum = 0.0;
  };
  Snapshot Read() const;

 private:
  std::vector<double> upperBounds_;
  std::unique_ptr<std::atomic<uint64_t>[]> counts_;  // per bucket, the last one +Inf
  std::atomic<uint64_t> count_{0};
  std::atomic<double> sum_{0.0};
};

/// Latency bounds in seconds, 5 ms to 5 min, for the views' histograms.
std::vector<double> LatencyBucketsSeconds();

/// Builds an exposition: each family's # HELP and # TYPE line once, before
/// its samples. Names and label names must be valid (checked: an invalid one
/// is a programming error); label values are escaped.
class ExpositionWriter {
 public:
  /// Starts a family. `type`: counter, gauge, histogram or untyped. A
  /// family started twice writes its HELP/TYPE lines only the first time.
  void Family(std::string_view name, std::string_view type, std::string_view help);
  /// One sample of the current family (for a counter, `name` ends in _total).
  void Sample(std::string_view name, double value, const Labels& labels = {});
  /// A whole histogram family: _bucket lines with `le`, _sum and _count.
  void WriteHistogram(std::string_view name, std::string_view help, const Histogram::Snapshot& snapshot,
                      const Labels& labels = {});

  const std::string& Text() const { return text_; }

 private:
  std::string text_;
  std::vector<std::string> families_;
};

/// How one named counter of a tier (the names StatsReply carries,
/// docs/protocol.md) is exported. `statsName` may hold one '*', which
/// matches any text (e.g. "renderer.*.connected"); the matched text becomes
/// the value of label `label`. Without '*', a non-empty `label` and
/// `labelValue` add that fixed label (several counters in one family).
struct CounterSpec {
  std::string_view statsName;
  std::string_view family;  // full Prometheus name; counters end in _total
  std::string_view type;    // counter or gauge
  std::string_view help;
  std::string_view label = {};
  std::string_view labelValue = {};
};

/// Writes `counters` (name, value; as a tier assembles them for StatsReply)
/// by `specs`, each family's samples grouped. A counter no spec matches is
/// written as a gauge `<prefix>_<name>` (invalid characters as '_'), so a
/// counter added to a tier is never silently dropped.
void WriteCounters(ExpositionWriter& out, std::string_view prefix,
                   const std::vector<std::pair<std::string, double>>& counters,
                   const std::vector<CounterSpec>& specs);

/// A value as the exposition format writes it (+Inf, -Inf, NaN, shortest
/// round-trip decimal otherwise).
std::string FormatValue(double value);

struct ParsedSample {
  std::string name;
  Labels labels;
  double value = 0.0;

  /// The value of label `key`, or nullopt.
  std::optional<std::string> Label(std::string_view key) const;
};

struct ParsedFamily {
  std::string name;
  std::string type = "untyped";
  std::string help;
};

struct Exposition {
  std::vector<ParsedFamily> families;  // in the order they were declared
  std::vector<ParsedSample> samples;   // in text order

  const ParsedFamily* FindFamily(std::string_view name) const;
  /// The first sample named `name` whose labels include `labels`.
  const ParsedSample* Find(std::string_view name, const Labels& labels = {}) const;
  /// The family a sample belongs to (a histogram's _bucket/_sum/_count
  /// belong to the histogram), or nullptr for an undeclared one.
  const ParsedFamily* FamilyOf(const ParsedSample& sample) const;
};

/// Parses the text exposition format strictly: every line must be a
/// comment, a # HELP / # TYPE line, a sample, or empty. Errors name the line.
/// A TYPE line after its family's samples, or twice, is an error too.
Expected<Exposition> ParseExposition(std::string_view text);

/// The process's resident set size in bytes (/proc/self/statm), or nullopt
/// where /proc is unavailable.
std::optional<uint64_t> ResidentMemoryBytes();

}  // namespace penumbra::metrics
