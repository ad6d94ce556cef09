#include "penumbra/common/operator_http.h"

#include "penumbra/common/version.h"

namespace penumbra {

namespace {
constexpr const char* kExpositionType = "text/plain; version=0.0.4; charset=utf-8";
}

Expected<std::unique_ptr<OperatorEndpoint>> OperatorEndpoint::Start(const HostPort& where, std::string prefix,
                                                                     net::HttpServerOptions options) {
  std::unique_ptr<OperatorEndpoint> endpoint(new OperatorEndpoint(std::move(prefix)));
  OperatorEndpoint* self = endpoint.get();
  net::HttpServer::Routes routes;
  routes["/healthz"] = [] { return net::HttpResponse{200, "text/plain; charset=utf-8", "ok\n"}; };
  routes["/readyz"] = [self] { return self->Ready(); };
  routes["/metrics"] = [self] { return self->Metrics(); };
  auto http = net::HttpServer::Start(where, std::move(routes), options);
  if (!http) return http.error();
  endpoint->http_ = std::move(*http);
  return endpoint;
}

Expected<std::unique_ptr<OperatorEndpoint>> OperatorEndpoint::FromFlags(const std::string& httpFlag,
                                                                         const std::string& portFile,
                                                                         std::string prefix) {
  if (httpFlag.empty()) return std::unique_ptr<OperatorEndpoint>();
  auto where = ParseHostPort(httpFlag, /*allowPortZero=*/true);
  if (!where) return Fail("--http: " + where.error().message);
  auto endpoint = Start(*where, std::move(prefix));
  if (!endpoint) return endpoint.error();
  if (!portFile.empty()) {
    if (auto written = WritePortFile(portFile, (*endpoint)->Endpoint().port()); !written)
      return Fail("--http-port-file: " + written.error().message);
  }
  return endpoint;
}

OperatorEndpoint::~OperatorEndpoint() { Stop(); }

void OperatorEndpoint::Stop() {
  if (http_) http_->Stop();
}

void OperatorEndpoint::Attach(OperatorProbe probe) {
  std::lock_guard lock(probeMutex_);
  probe_ = std::move(probe);
}

void OperatorEndpoint::Detach() {
  std::lock_guard lock(probeMutex_);
  probe_.reset();
}

std::string OperatorEndpoint::NotReadyReason() {
  if (!probe_) return "loading the scene";
  return probe_->notReadyReason ? probe_->notReadyReason() : std::string();
}

net::HttpResponse OperatorEndpoint::Ready() {
  std::lock_guard lock(probeMutex_);
  const std::string reason = NotReadyReason();
  if (reason.empty()) return {200, "text/plain; charset=utf-8", "ready\n"};
  return {503, "text/plain; charset=utf-8", "not ready: " + reason + "\n"};
}

net::HttpResponse OperatorEndpoint::Metrics() {
  metrics::ExpositionWriter out;
  out.Family(prefix_ + "_build_info", "gauge", "Always 1; the version is a label");
  out.Sample(prefix_ + "_build_info", 1.0, {{"version", std::string(kVersion)}});
  out.Family(prefix_ + "_uptime_seconds", "gauge", "Seconds since the process started serving HTTP");
  out.Sample(prefix_ + "_uptime_seconds",
             std::chrono::duration<double>(std::chrono::steady_clock::now() - started_).count());
  if (auto rss = metrics::ResidentMemoryBytes()) {
    out.Family(prefix_ + "_resident_memory_bytes", "gauge", "Resident set size (/proc/self/statm)");
    out.Sample(prefix_ + "_resident_memory_bytes", double(*rss));
  }
  std::lock_guard lock(probeMutex_);
  out.Family(prefix_ + "_ready", "gauge", "1 when /readyz answers 200");
  out.Sample(prefix_ + "_ready", NotReadyReason().empty() ? 1.0 : 0.0);
  if (probe_ && probe_->writeMetrics) probe_->writeMetrics(out);
  return {200, kExpositionType, out.Text()};
}

}  // namespace penumbra
