#pragma once
// Several "hosts" on one machine, for multi-host tests: each host is a Linux
// network namespace with one interface (eth0, 10.200.0.x/24) on a bridge. The
// bridge lives in a namespace of its own, so the machine's own interfaces,
// routes and firewall are never touched, and deleting the namespaces deletes
// every interface. Processes are started on a host with `ip netns exec`, which
// also gives them the host's own /etc/hosts (see SetHostsFile).
//
// Needs root (CAP_SYS_ADMIN and CAP_NET_ADMIN) and iproute2; Create() says
// why when it cannot, so that a test can skip with that reason.
//
// Names are unique per process and network (pnb<pid>n<k>-<host>). The
// destructor deletes every namespace and hosts file it made; leftovers of a
// run that died without it are deleted by the next Create() once their
// process is gone.

#include <memory>
#include <optional>
#include <string>
#include <thread>
#include <type_traits>
#include <utility>
#include <vector>

#include "penumbra/common/expected.h"
#include "support/process.h"

namespace penumbra::testing {

class VirtualNetwork {
 public:
  /// Creates the bridge. Fails with the reason when namespaces cannot be made
  /// here (not root, no `ip`, or the kernel refused).
  static Expected<std::unique_ptr<VirtualNetwork>> Create();
  ~VirtualNetwork();
  VirtualNetwork(const VirtualNetwork&) = delete;
  VirtualNetwork& operator=(const VirtualNetwork&) = delete;

  /// Adds a host on the bridge and returns its address.
  Expected<std::string> AddHost(const std::string& host);
  /// The address AddHost gave `host`.
  const std::string& Address(const std::string& host) const;

  /// Sets /etc/hosts as processes started on `host` see it: localhost plus
  /// `entries` ({name, address}; a name listed with several addresses
  /// resolves to all of them). The first call must come before the host's
  /// processes start; later calls rewrite the file in place, and running
  /// processes see the change at their next lookup.
  Status SetHostsFile(const std::string& host, const std::vector<std::pair<std::string, std::string>>& entries);

  /// Starts `exe args...` on `host`; the process is the executable itself
  /// (ip netns exec execs it), so signals reach it directly. It is killed
  /// when the calling thread ends: call from the test's own thread.
  Expected<ChildProcess> Spawn(const std::string& host, const std::string& exe, const std::vector<std::string>& args,
                               const std::string& logPath) const;

  /// Runs `fn` on a thread that has joined `host`'s network namespace and
  /// returns its result, an Expected<T> or a Status (the failure to join the
  /// namespace, if any, in its place). Sockets `fn` opens stay in that
  /// namespace, so the objects holding them work from any thread afterwards.
  template <class F>
  std::invoke_result_t<F> RunOnHost(const std::string& host, F&& fn) const {
    std::optional<std::invoke_result_t<F>> result;
    std::thread([&] {
      if (Status entered = EnterNamespace(host); !entered.ok())
        result.emplace(entered.error());
      else
        result.emplace(fn());
    }).join();
    return std::move(*result);
  }

 private:
  VirtualNetwork(std::string ip, std::string prefix) : ip_(std::move(ip)), prefix_(std::move(prefix)) {}
  std::string Namespace(const std::string& host) const { return prefix_ + "-" + host; }
  Status Ip(const std::vector<std::string>& args) const;
  Status EnterNamespace(const std::string& host) const;

  std::string ip_;      // path of the `ip` executable
  std::string prefix_;  // pnb<pid>n<k>
  std::vector<std::pair<std::string, std::string>> hosts_;  // {host, address}
  bool bridge_ = false;
  std::vector<std::string> hostsFiles_;  // /etc/netns/<namespace> directories made
};

}  // namespace penumbra::testing
