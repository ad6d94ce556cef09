#include "penumbra/common/metrics.h"

#include <unistd.h>

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <fstream>

#include <fmt/format.h>

#include "penumbra/common/check.h"

namespace penumbra::metrics {

namespace {

bool IsNameStart(char c) { return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || c == '_' || c == ':'; }
bool IsNameChar(char c) { return IsNameStart(c) || (c >= '0' && c <= '9'); }

bool ValidMetricName(std::string_view name) {
  if (name.empty() || !IsNameStart(name[0])) return false;
  return std::all_of(name.begin(), name.end(), IsNameChar);
}

bool ValidLabelName(std::string_view name) {
  return ValidMetricName(name) && name.find(':') == std::string_view::npos;
}

void AppendEscaped(std::string& out, std::string_view value, bool quote) {
  for (char c : value) {
    if (c == '\\') out += "\\\\";
    else if (c == '\n') out += "\\n";
    else if (quote && c == '"') out += "\\\"";
    else out += c;
  }
}

bool IsKnownType(std::string_view type) {
  return type == "counter" || type == "gauge" || type == "histogram" || type == "summary" || type == "untyped";
}

// The family a sample name belongs to, given its declared families:
// histogram and summary samples carry a suffix.
std::string_view BaseName(std::string_view name, const std::vector<ParsedFamily>& families) {
  for (std::string_view suffix : {"_bucket", "_sum", "_count"}) {
    if (name.size() > suffix.size() && name.substr(name.size() - suffix.size()) == suffix) {
      const std::string_view base = name.substr(0, name.size() - suffix.size());
      for (const ParsedFamily& f : families)
        if (f.name == base && (f.type == "histogram" || f.type == "summary")) return base;
    }
  }
  return name;
}

Expected<double> ParseValue(std::string_view text) {
  if (text == "+Inf" || text == "Inf") return std::numeric_limits<double>::infinity();
  if (text == "-Inf") return -std::numeric_limits<double>::infinity();
  if (text == "NaN") return std::numeric_limits<double>::quiet_NaN();
  double value = 0.0;
  const char* end = text.data() + text.size();
  auto [ptr, ec] = std::from_chars(text.data(), end, value);
  if (text.empty() || ec != std::errc() || ptr != end) return Fail(fmt::format("'{}' is not a number", text));
  return value;
}

}  // namespace

// --- Histogram ----------------------------------------------------------------

Histogram::Histogram(std::vector<double> upperBounds)
    : upperBounds_(std::move(upperBounds)), counts_(new std::atomic<uint64_t>[upperBounds_.size() + 1]) {
  for (size_t i = 0; i < upperBounds_.size(); ++i) {
    PENUMBRA_CHECK(std::isfinite(upperBounds_[i]), "histogram bounds must be finite");
    PENUMBRA_CHECK(i == 0 || upperBounds_[i - 1] < upperBounds_[i], "histogram bounds must increase");
  }
  for (size_t i = 0; i <= upperBounds_.size(); ++i) counts_[i] = 0;
}

void Histogram::Observe(double value) {
  const size_t bucket = size_t(std::lower_bound(upperBounds_.begin(), upperBounds_.end(), value) - upperBounds_.begin());
  counts_[bucket].fetch_add(1, std::memory_order_relaxed);
  sum_.fetch_add(value, std::memory_order_relaxed);
  count_.fetch_add(1, std::memory_order_relaxed);
}

Histogram::Snapshot Histogram::Read() const {
  Snapshot s;
  s.upperBounds = upperBounds_;
  uint64_t running = 0;
  for (size_t i = 0; i <= upperBounds_.size(); ++i) {
    running += counts_[i].load(std::memory_order_relaxed);
    s.cumulative.push_back(running);
  }
  // The +Inf bucket must equal _count for a valid exposition: derive the
  // count from the buckets rather than reading count_ a moment later.
  s.count = running;
  s.sum = sum_.load(std::memory_order_relaxed);
  return s;
}

std::vector<double> LatencyBucketsSeconds() {
  return {0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1, 2.5, 5, 10, 30, 60, 120, 300};
}

// --- Writing ------------------------------------------------------------------

std::string FormatValue(double value) {
  if (std::isnan(value)) return "NaN";
  if (std::isinf(value)) return value > 0 ? "+Inf" : "-Inf";
  return fmt::format("{}", value);
}

void ExpositionWriter::Family(std::string_view name, std::string_view type, std::string_view help) {
  PENUMBRA_CHECK(ValidMetricName(name), "invalid metric name");
  PENUMBRA_CHECK(IsKnownType(type), "unknown metric type");
  if (std::find(families_.begin(), families_.end(), name) != families_.end()) return;
  families_.emplace_back(name);
  text_ += "# HELP ";
  text_ += name;
  text_ += ' ';
  AppendEscaped(text_, help, /*quote=*/false);
  text_ += "\n# TYPE ";
  text_ += name;
  text_ += ' ';
  text_ += type;
  text_ += '\n';
}

void ExpositionWriter::Sample(std::string_view name, double value, const Labels& labels) {
  PENUMBRA_CHECK(ValidMetricName(name), "invalid metric name");
  text_ += name;
  if (!labels.empty()) {
    text_ += '{';
    for (size_t i = 0; i < labels.size(); ++i) {
      PENUMBRA_CHECK(ValidLabelName(labels[i].first), "invalid label name");
      if (i > 0) text_ += ',';
      text_ += labels[i].first;
      text_ += "=\"";
      AppendEscaped(text_, labels[i].second, /*quote=*/true);
      text_ += '"';
    }
    text_ += '}';
  }
  text_ += ' ';
  text_ += FormatValue(value);
  text_ += '\n';
}

void ExpositionWriter::WriteHistogram(std::string_view name, std::string_view help,
                                      const Histogram::Snapshot& snapshot, const Labels& labels) {
  Family(name, "histogram", help);
  const std::string bucket = std::string(name) + "_bucket";
  for (size_t i = 0; i < snapshot.cumulative.size(); ++i) {
    Labels withLe = labels;
    withLe.emplace_back("le", i < snapshot.upperBounds.size() ? FormatValue(snapshot.upperBounds[i]) : "+Inf");
    Sample(bucket, double(snapshot.cumulative[i]), withLe);
  }
  Sample(std::string(name) + "_sum", snapshot.sum, labels);
  Sample(std::string(name) + "_count", double(snapshot.count), labels);
}

void WriteCounters(ExpositionWriter& out, std::string_view prefix,
                   const std::vector<std::pair<std::string, double>>& counters,
                   const std::vector<CounterSpec>& specs) {
  struct Family {
    std::string name, type, help;
    std::vector<std::pair<double, Labels>> samples;
  };
  std::vector<Family> families;  // in order of first appearance
  auto familyFor = [&](std::string_view name, std::string_view type, std::string_view help) -> Family& {
    for (Family& f : families)
      if (f.name == name) return f;
    families.push_back(Family{std::string(name), std::string(type), std::string(help), {}});
    return families.back();
  };
  for (const auto& [name, value] : counters) {
    const CounterSpec* match = nullptr;
    std::string captured;
    for (const CounterSpec& spec : specs) {
      const size_t star = spec.statsName.find('*');
      if (star == std::string_view::npos) {
        if (spec.statsName == name) match = &spec;
      } else {
        const std::string_view head = spec.statsName.substr(0, star), tail = spec.statsName.substr(star + 1);
        if (name.size() > head.size() + tail.size() && std::string_view(name).starts_with(head) &&
            std::string_view(name).ends_with(tail)) {
          match = &spec;
          captured = name.substr(head.size(), name.size() - head.size() - tail.size());
        }
      }
      if (match) break;
    }
    if (!match) {
      std::string fallback = std::string(prefix) + "_";
      for (char c : name) fallback += IsNameChar(c) && c != ':' ? c : '_';
      familyFor(fallback, "gauge", fmt::format("StatsReply counter '{}' (docs/protocol.md)", name))
          .samples.push_back({value, {}});
      continue;
    }
    Labels labels;
    if (!match->label.empty())
      labels.emplace_back(std::string(match->label),
                          match->statsName.find('*') != std::string_view::npos ? captured
                                                                                : std::string(match->labelValue));
    familyFor(match->family, match->type, match->help).samples.push_back({value, std::move(labels)});
  }
  for (const Family& f : families) {
    out.Family(f.name, f.type, f.help);
    for (const auto& [value, labels] : f.samples) out.Sample(f.name, value, labels);
  }
}

// --- Parsing ------------------------------------------------------------------

std::optional<std::string> ParsedSample::Label(std::string_view key) const {
  for (const auto& [k, v] : labels)
    if (k == key) return v;
  return std::nullopt;
}

const ParsedFamily* Exposition::FindFamily(std::string_view name) const {
  for (const ParsedFamily& f : families)
    if (f.name == name) return &f;
  return nullptr;
}

const ParsedSample* Exposition::Find(std::string_view name, const Labels& labels) const {
  for (const ParsedSample& s : samples) {
    if (s.name != name) continue;
    bool all = true;
    for (const auto& [k, v] : labels) all = all && s.Label(k) == v;
    if (all) return &s;
  }
  return nullptr;
}

const ParsedFamily* Exposition::FamilyOf(const ParsedSample& sample) const {
  return FindFamily(BaseName(sample.name, families));
}

Expected<Exposition> ParseExposition(std::string_view text) {
  Exposition out;
  std::vector<std::string> seenSamplesOf;  // families that already have samples
  size_t lineNumber = 0;
  while (!text.empty()) {
    ++lineNumber;
    const size_t eol = text.find('\n');
    std::string_view line = text.substr(0, eol);
    text = eol == std::string_view::npos ? std::string_view() : text.substr(eol + 1);
    auto bad = [&](const std::string& why) { return Fail(fmt::format("line {}: {}: '{}'", lineNumber, why, line)); };
    if (line.empty()) continue;
    if (line[0] == '#') {
      // "# HELP name text", "# TYPE name type"; any other comment is free.
      std::string_view rest = line.substr(1);
      while (!rest.empty() && rest[0] == ' ') rest.remove_prefix(1);
      const bool help = rest.starts_with("HELP "), type = rest.starts_with("TYPE ");
      if (!help && !type) continue;
      rest.remove_prefix(5);
      while (!rest.empty() && rest[0] == ' ') rest.remove_prefix(1);
      const size_t space = rest.find(' ');
      const std::string name(rest.substr(0, space));
      const std::string_view tail = space == std::string_view::npos ? std::string_view() : rest.substr(space + 1);
      if (!ValidMetricName(name)) return bad("invalid metric name in a HELP/TYPE line");
      ParsedFamily* family = nullptr;
      for (ParsedFamily& f : out.families)
        if (f.name == name) family = &f;
      if (type) {
        if (!IsKnownType(tail)) return bad("unknown metric type");
        if (family && family->type != "untyped") return bad("second TYPE line for the family");
        if (std::find(seenSamplesOf.begin(), seenSamplesOf.end(), name) != seenSamplesOf.end())
          return bad("TYPE line after the family's samples");
      }
      if (!family) {
        out.families.push_back(ParsedFamily{name, "untyped", ""});
        family = &out.families.back();
      }
      if (type) family->type = std::string(tail);
      if (help) {
        std::string unescaped;
        for (size_t i = 0; i < tail.size(); ++i) {
          if (tail[i] == '\\' && i + 1 < tail.size() && (tail[i + 1] == '\\' || tail[i + 1] == 'n')) {
            unescaped += tail[i + 1] == 'n' ? '\n' : '\\';
            ++i;
          } else {
            unescaped += tail[i];
          }
        }
        family->help = std::move(unescaped);
      }
      continue;
    }
    ParsedSample sample;
    size_t i = 0;
    while (i < line.size() && IsNameChar(line[i])) ++i;
    sample.name = std::string(line.substr(0, i));
    if (!ValidMetricName(sample.name)) return bad("invalid metric name");
    if (i < line.size() && line[i] == '{') {
      ++i;
      for (;;) {
        while (i < line.size() && line[i] == ' ') ++i;
        if (i < line.size() && line[i] == '}') {
          ++i;
          break;
        }
        const size_t start = i;
        while (i < line.size() && IsNameChar(line[i])) ++i;
        const std::string key(line.substr(start, i - start));
        if (!ValidLabelName(key)) return bad("invalid label name");
        if (i >= line.size() || line[i] != '=') return bad("expected '=' after a label name");
        ++i;
        if (i >= line.size() || line[i] != '"') return bad("label value is not quoted");
        ++i;
        std::string value;
        bool closed = false;
        while (i < line.size()) {
          const char c = line[i++];
          if (c == '"') {
            closed = true;
            break;
          }
          if (c == '\\') {
            if (i >= line.size()) break;
            const char e = line[i++];
            if (e == 'n') value += '\n';
            else if (e == '\\' || e == '"') value += e;
            else return bad("invalid escape in a label value");
          } else {
            value += c;
          }
        }
        if (!closed) return bad("unterminated label value");
        for (const auto& [k, v] : sample.labels)
          if (k == key) return bad("label '" + key + "' given twice");
        sample.labels.emplace_back(key, std::move(value));
        while (i < line.size() && line[i] == ' ') ++i;
        if (i < line.size() && line[i] == ',') {
          ++i;
          continue;
        }
        if (i < line.size() && line[i] == '}') {
          ++i;
          break;
        }
        return bad("expected ',' or '}' after a label");
      }
    }
    if (i >= line.size() || line[i] != ' ') return bad("expected a space before the value");
    while (i < line.size() && line[i] == ' ') ++i;
    std::string_view rest = line.substr(i);
    const size_t space = rest.find(' ');
    auto value = ParseValue(rest.substr(0, space));
    if (!value) return bad(value.error().message);
    sample.value = *value;
    if (space != std::string_view::npos) {  // an optional timestamp, integer milliseconds
      std::string_view ts = rest.substr(space + 1);
      int64_t t = 0;
      auto [ptr, ec] = std::from_chars(ts.data(), ts.data() + ts.size(), t);
      if (ts.empty() || ec != std::errc() || ptr != ts.data() + ts.size()) return bad("invalid timestamp");
    }
    // A family's samples form one group: a family seen before, then left,
    // must not come back.
    const std::string base(BaseName(sample.name, out.families));
    if (seenSamplesOf.empty() || seenSamplesOf.back() != base) {
      if (std::find(seenSamplesOf.begin(), seenSamplesOf.end(), base) != seenSamplesOf.end())
        return bad("the samples of '" + base + "' are not one group");
      seenSamplesOf.push_back(base);
    }
    out.samples.push_back(std::move(sample));
  }
  return out;
}

// --- Process ------------------------------------------------------------------

std::optional<uint64_t> ResidentMemoryBytes() {
  // statm: size resident shared text lib data dt, in pages.
  std::FILE* f = std::fopen("/proc/self/statm", "r");
  if (!f) return std::nullopt;
  unsigned long long size = 0, resident = 0;
  const int n = std::fscanf(f, "%llu %llu", &size, &resident);
  std::fclose(f);
  if (n != 2) return std::nullopt;
  const long page = sysconf(_SC_PAGESIZE);
  return uint64_t(resident) * uint64_t(page > 0 ? page : 4096);
}

}  // namespace penumbra::metrics
