#include "support/netns.h"

#include <fcntl.h>
#include <sched.h>
#include <signal.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <regex>
#include <sstream>

#include <fmt/format.h>

namespace penumbra::testing {

namespace fs = std::filesystem;

namespace {

const fs::path kNamespaceDir = "/run/netns";  // where `ip netns add` pins namespaces
const fs::path kHostsFileDir = "/etc/netns";  // per-namespace /etc files of `ip netns exec`
const std::string kSubnet = "10.200.0.";      // hosts are .2, .3, ... on the bridge

// Namespaces and hosts files of networks whose process has died, and any
// process still inside those namespaces.
void RemoveStale(const std::string& ip) {
  static const std::regex kOurs("pnb([0-9]+)n[0-9]+-.+");
  std::error_code ec;
  for (const fs::path& dir : {kNamespaceDir, kHostsFileDir}) {
    for (const auto& entry : fs::directory_iterator(dir, ec)) {
      const std::string name = entry.path().filename().string();
      std::smatch m;
      if (!std::regex_match(name, m, kOurs)) continue;
      const pid_t owner = pid_t(std::stol(m[1].str()));
      if (::kill(owner, 0) == 0 || errno != ESRCH) continue;  // still running
      if (dir == kHostsFileDir) {
        fs::remove_all(entry.path(), ec);
        continue;
      }
      if (auto pids = RunCommand(ip, {"netns", "pids", name})) {
        std::istringstream list(*pids);
        for (pid_t pid; list >> pid;) ::kill(pid, SIGKILL);
      }
      (void)RunCommand(ip, {"netns", "delete", name});
    }
  }
}

}  // namespace

Expected<std::unique_ptr<VirtualNetwork>> VirtualNetwork::Create() {
  if (::geteuid() != 0)
    return Fail(fmt::format("network namespaces need root (CAP_SYS_ADMIN and CAP_NET_ADMIN); running as uid {}",
                            ::geteuid()));
  const std::optional<std::string> ip = FindExecutable("ip");
  if (!ip) return Fail("no `ip` command (Debian package iproute2; scripts/install-deps.sh installs it)");
  RemoveStale(*ip);
  static std::atomic<int> networks{0};
  std::unique_ptr<VirtualNetwork> net(new VirtualNetwork(*ip, fmt::format("pnb{}n{}", ::getpid(), networks++)));
  const std::string bridge = net->Namespace("switch");
  if (auto ok = net->Ip({"netns", "add", bridge}); !ok)
    return Fail("cannot create a network namespace: " + ok.error().message);
  net->bridge_ = true;
  for (const auto& args : std::vector<std::vector<std::string>>{
           {"-n", bridge, "link", "add", "br0", "type", "bridge"},
           {"-n", bridge, "link", "set", "br0", "up"}}) {
    if (auto ok = net->Ip(args); !ok) return ok.error();
  }
  return net;
}

VirtualNetwork::~VirtualNetwork() {
  std::error_code ec;
  // Deleting a namespace deletes its end of each veth pair, and with it the
  // other end; processes still inside keep the namespace alive until they end.
  for (const auto& [host, address] : hosts_) (void)Ip({"netns", "delete", Namespace(host)});
  if (bridge_) (void)Ip({"netns", "delete", Namespace("switch")});
  for (const auto& dir : hostsFiles_) fs::remove_all(dir, ec);
  if (!hostsFiles_.empty()) fs::remove(kHostsFileDir, ec);  // only if no other network uses it
}

Status VirtualNetwork::Ip(const std::vector<std::string>& args) const {
  auto output = RunCommand(ip_, args);
  if (!output) return output.error();
  return Status::Ok();
}

Expected<std::string> VirtualNetwork::AddHost(const std::string& host) {
  const std::string ns = Namespace(host);
  const std::string address = kSubnet + std::to_string(hosts_.size() + 2);
  const std::string port = fmt::format("v{}", hosts_.size());  // the bridge's end, inside the switch namespace
  if (auto ok = Ip({"netns", "add", ns}); !ok) return ok.error();
  hosts_.emplace_back(host, address);
  const std::string bridge = Namespace("switch");
  for (const auto& args : std::vector<std::vector<std::string>>{
           {"-n", bridge, "link", "add", port, "type", "veth", "peer", "name", "eth0", "netns", ns},
           {"-n", bridge, "link", "set", port, "master", "br0"},
           {"-n", bridge, "link", "set", port, "up"},
           {"-n", ns, "addr", "add", address + "/24", "dev", "eth0"},
           {"-n", ns, "link", "set", "eth0", "up"},
           {"-n", ns, "link", "set", "lo", "up"}}) {
    if (auto ok = Ip(args); !ok) return ok.error();
  }
  return address;
}

const std::string& VirtualNetwork::Address(const std::string& host) const {
  for (const auto& [name, address] : hosts_)
    if (name == host) return address;
  static const std::string kNone;
  return kNone;
}

Status VirtualNetwork::SetHostsFile(const std::string& host,
                                    const std::vector<std::pair<std::string, std::string>>& entries) {
  const fs::path dir = kHostsFileDir / Namespace(host);
  std::error_code ec;
  if (!fs::exists(dir)) {
    fs::create_directories(dir, ec);
    if (ec) return Fail(fmt::format("cannot create {}: {}", dir.string(), ec.message()));
    hostsFiles_.push_back(dir.string());
  }
  std::string text = "127.0.0.1 localhost\n::1 localhost\n";
  for (const auto& [name, address] : entries) text += address + " " + name + "\n";
  // Rewritten in place (not replaced): running processes see this inode
  // through the bind mount `ip netns exec` made at their start.
  std::ofstream out(dir / "hosts", std::ios::binary | std::ios::trunc);
  out << text;
  out.close();
  if (!out) return Fail(fmt::format("cannot write {}", (dir / "hosts").string()));
  return Status::Ok();
}

Expected<ChildProcess> VirtualNetwork::Spawn(const std::string& host, const std::string& exe,
                                             const std::vector<std::string>& args, const std::string& logPath) const {
  // setpriv (util-linux) makes the process die with the thread that started
  // it, so that nothing outlives a test that crashed or was killed.
  const std::optional<std::string> setpriv = FindExecutable("setpriv");
  if (!setpriv) return Fail("no `setpriv` (Debian package util-linux)");
  std::vector<std::string> all = {"netns", "exec", Namespace(host), *setpriv, "--pdeathsig", "KILL", "--", exe};
  all.insert(all.end(), args.begin(), args.end());
  return ChildProcess::Spawn(ip_, all, logPath);
}

Status VirtualNetwork::EnterNamespace(const std::string& host) const {
  const fs::path path = kNamespaceDir / Namespace(host);
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) return Fail(fmt::format("cannot open {}: {}", path.string(), std::strerror(errno)));
  const int rc = ::setns(fd, CLONE_NEWNET);
  const int error = errno;
  ::close(fd);
  if (rc != 0) return Fail(fmt::format("cannot join {}: {}", path.string(), std::strerror(error)));
  return Status::Ok();
}

}  // namespace penumbra::testing
