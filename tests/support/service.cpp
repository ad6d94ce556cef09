#include "support/service.h"

namespace penumbra::testing {

Expected<Service> StartService(const std::string& exe, const std::vector<std::string>& args, const std::string& tag,
                               std::chrono::milliseconds timeout) {
  Service service;
  service.dir = MakeTempDir("penumbra-" + tag);
  const std::string portFile = service.dir + "/port";
  std::vector<std::string> all = args;
  all.insert(all.end(), {"--listen", "127.0.0.1:0", "--port-file", portFile});
  auto process = ChildProcess::Spawn(exe, all, service.dir + "/" + tag + ".log");
  if (!process) return process.error();
  service.process = std::move(*process);
  auto port = WaitForPortFile(service.process, portFile, timeout);
  if (!port) return port.error();
  service.port = *port;
  return service;
}

}  // namespace penumbra::testing
