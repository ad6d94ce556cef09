// penumbra-stats: fetches a renderer's or an SMA's /metrics (their --http
// endpoint) and prints the figures for a human: one aligned line each, with
// units; histograms as count, mean and estimated percentiles.
//
//   penumbra-stats 127.0.0.1:9200            # the figures; exit 1 if unreachable
//   penumbra-stats --ready 127.0.0.1:9200    # exit 0 iff /readyz answers 200 (a health check)
//   penumbra-stats --raw 127.0.0.1:9200      # the exposition text as served

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <optional>
#include <string>

#include <CLI/CLI.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <fmt/format.h>

#include "penumbra/common/asio.h"
#include "penumbra/common/endpoint.h"
#include "penumbra/common/expected.h"
#include "penumbra/common/metrics.h"
#include "penumbra/common/version.h"

namespace {

using namespace penumbra;
namespace beast = boost::beast;
namespace http = boost::beast::http;
using boost::system::error_code;

struct Reply {
  unsigned status = 0;
  std::string body;
};

// GET http://where/path within `timeout` (connect, send and receive in all).
Expected<Reply> Get(const HostPort& where, const std::string& path, std::chrono::milliseconds timeout) {
  asio::io_context io;
  tcp::resolver resolver(io);
  beast::tcp_stream stream(io);
  http::request<http::empty_body> request{http::verb::get, path, 11};
  request.set(http::field::host, where.host);
  request.set(http::field::user_agent, "penumbra-stats");
  beast::flat_buffer buffer;
  http::response_parser<http::string_body> parser;
  parser.body_limit(64 << 20);
  error_code failure;
  std::string step = "resolve";
  auto fail = [&](const error_code& ec, const char* what) {
    failure = ec;
    step = what;
  };
  resolver.async_resolve(where.host, std::to_string(where.port),
                         [&](const error_code& resolved, tcp::resolver::results_type addresses) {
    if (resolved) return fail(resolved, "resolve");
    stream.expires_after(timeout);
    stream.async_connect(addresses, [&](const error_code& connected, const tcp::endpoint&) {
      if (connected) return fail(connected, "connect");
      http::async_write(stream, request, [&](const error_code& sent, size_t) {
        if (sent) return fail(sent, "send");
        http::async_read(stream, buffer, parser, [&](const error_code& received, size_t) {
          if (received) return fail(received, "receive");
          error_code ignored;
          stream.socket().shutdown(tcp::socket::shutdown_both, ignored);
        });
      });
    });
  });
  io.run();
  if (failure)
    return Fail(fmt::format("http://{}{}: {} failed: {}", where.ToString(), path, step, failure.message()));
  return Reply{parser.get().result_int(), parser.get().body()};
}

std::string Scaled(double value, const char* const* units, int count, double step) {
  int i = 0;
  while (std::fabs(value) >= step && i + 1 < count) {
    value /= step;
    ++i;
  }
  return i == 0 ? fmt::format("{:.0f} {}", value, units[0]) : fmt::format("{:.1f} {}", value, units[i]);
}

std::string Seconds(double s) {
  if (std::fabs(s) < 1.0) return fmt::format("{:.1f} ms", s * 1000.0);
  if (std::fabs(s) < 120.0) return fmt::format("{:.2f} s", s);
  if (std::fabs(s) < 7200.0) return fmt::format("{:.1f} min", s / 60.0);
  return fmt::format("{:.1f} h", s / 3600.0);
}

std::string Count(double v) {
  if (v != std::floor(v) || std::fabs(v) >= 1e15) return fmt::format("{:.4g}", v);
  std::string digits = fmt::format("{:.0f}", std::fabs(v)), out;
  for (size_t i = 0; i < digits.size(); ++i) {
    if (i > 0 && (digits.size() - i) % 3 == 0) out += ',';
    out += digits[i];
  }
  return v < 0 ? "-" + out : out;
}

// A value with the unit its family's name gives.
std::string Human(const std::string& family, double v) {
  static const char* const kBytes[] = {"B", "KiB", "MiB", "GiB", "TiB"};
  if (std::isnan(v) || std::isinf(v)) return metrics::FormatValue(v);
  if (family.ends_with("_bytes")) return Scaled(v, kBytes, 5, 1024.0);
  if (family.ends_with("_seconds")) return Seconds(v);
  if (family.ends_with("_ratio")) return fmt::format("{:.1f} %", v * 100.0);
  if (family.ends_with("_per_second")) return fmt::format("{:.1f} /s", v);
  return Count(v);
}

// Estimated quantile from cumulative buckets (linear within a bucket, as
// Prometheus' histogram_quantile does).
std::optional<double> Quantile(const std::vector<std::pair<double, double>>& buckets, double q) {
  if (buckets.empty() || buckets.back().second <= 0.0) return std::nullopt;
  const double rank = q * buckets.back().second;
  double lowerBound = 0.0, lowerCount = 0.0;
  for (const auto& [bound, count] : buckets) {
    if (count >= rank) {
      if (std::isinf(bound)) return lowerBound;  // beyond the last finite bound: say at least that
      const double inBucket = count - lowerCount;
      return inBucket > 0 ? lowerBound + (bound - lowerBound) * (rank - lowerCount) / inBucket : bound;
    }
    lowerBound = bound;
    lowerCount = count;
  }
  return std::nullopt;
}

std::string DisplayName(const std::string& family, const std::string& prefix) {
  std::string name = family.starts_with(prefix) ? family.substr(prefix.size()) : family;
  for (std::string_view suffix : {"_total", "_seconds", "_bytes", "_ratio", "_per_second"})
    if (name.ends_with(suffix)) name.resize(name.size() - suffix.size());
  std::replace(name.begin(), name.end(), '_', ' ');
  return name;
}

std::string LabelText(const metrics::Labels& labels) {
  std::string out;
  for (const auto& [k, v] : labels) {
    if (k == "le") continue;
    out += out.empty() ? " [" : ", ";
    out += k + "=" + v;
  }
  return out.empty() ? out : out + "]";
}

void Print(const metrics::Exposition& e, const std::string& address) {
  // The tier's prefix: penumbra_sma_ or penumbra_renderer_, from build_info.
  std::string prefix, version;
  for (const auto& s : e.samples)
    if (s.name.ends_with("_build_info")) {
      prefix = s.name.substr(0, s.name.size() - std::string("build_info").size());
      version = s.Label("version").value_or("?");
    }
  std::vector<std::pair<std::string, std::string>> lines;
  for (const metrics::ParsedFamily& f : e.families) {
    if (f.name.ends_with("_build_info")) continue;
    const std::string name = DisplayName(f.name, prefix);
    if (f.type == "histogram") {
      std::vector<std::pair<double, double>> buckets;
      double sum = 0.0, count = 0.0;
      for (const auto& s : e.samples) {
        if (s.name == f.name + "_bucket") {
          const std::string le = s.Label("le").value_or("+Inf");
          buckets.emplace_back(le == "+Inf" ? INFINITY : std::strtod(le.c_str(), nullptr), s.value);
        } else if (s.name == f.name + "_sum") {
          sum = s.value;
        } else if (s.name == f.name + "_count") {
          count = s.value;
        }
      }
      std::string text = fmt::format("{} observed", Count(count));
      if (count > 0) {
        text += fmt::format(", mean {}", Seconds(sum / count));
        for (double q : {0.5, 0.9, 0.99})
          if (auto v = Quantile(buckets, q)) text += fmt::format(", p{:.0f} ~{}", q * 100, Seconds(*v));
      }
      lines.emplace_back(name, text);
      continue;
    }
    for (const auto& s : e.samples)
      if (s.name == f.name) lines.emplace_back(name + LabelText(s.labels), Human(f.name, s.value));
  }
  const std::string tier = prefix.empty() ? "?" : DisplayName(prefix.substr(0, prefix.size() - 1), "penumbra_");
  std::printf("%s %s at %s\n", tier.c_str(), version.c_str(), address.c_str());
  size_t width = 0;
  for (const auto& [k, v] : lines) width = std::max(width, k.size());
  for (const auto& [k, v] : lines) std::printf("  %-*s  %s\n", int(width), k.c_str(), v.c_str());
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"penumbra-stats: a renderer's or an SMA's metrics (their --http endpoint), for humans"};
  app.set_version_flag("--version", "penumbra-stats " + std::string(penumbra::kVersion));
  std::string address;
  bool ready = false, raw = false;
  double timeoutSeconds = 5.0;
  app.add_option("address", address, "The --http address of a renderer or an SMA, HOST:PORT")->required();
  app.add_flag("--ready", ready, "Only ask /readyz: exit 0 iff it answers 200 (for health checks)");
  app.add_flag("--raw", raw, "Print the exposition text as served");
  app.add_option("--timeout", timeoutSeconds, "Seconds to wait for the answer")
      ->check(CLI::Range(0.1, 600.0))->capture_default_str();
  CLI11_PARSE(app, argc, argv);

  auto where = penumbra::ParseHostPort(address);
  if (!where) {
    std::fprintf(stderr, "penumbra-stats: %s\n", where.error().message.c_str());
    return 2;
  }
  const auto timeout = std::chrono::milliseconds(int64_t(timeoutSeconds * 1000.0));
  auto reply = Get(*where, ready ? "/readyz" : "/metrics", timeout);
  if (!reply) {
    std::fprintf(stderr, "penumbra-stats: %s\n", reply.error().message.c_str());
    return 1;
  }
  if (ready) {
    std::fputs(reply->body.c_str(), reply->status == 200 ? stdout : stderr);
    return reply->status == 200 ? 0 : 1;
  }
  if (reply->status != 200) {
    std::fprintf(stderr, "penumbra-stats: http://%s/metrics answered %u: %s\n", address.c_str(), reply->status,
                 reply->body.c_str());
    return 1;
  }
  if (raw) {
    std::fputs(reply->body.c_str(), stdout);
    return 0;
  }
  auto parsed = penumbra::metrics::ParseExposition(reply->body);
  if (!parsed) {
    std::fprintf(stderr, "penumbra-stats: http://%s/metrics: %s\n", address.c_str(), parsed.error().message.c_str());
    return 1;
  }
  Print(*parsed, address);
  return 0;
}
