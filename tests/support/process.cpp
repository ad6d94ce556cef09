#include "process.h"

#include <fcntl.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <thread>

#include <fmt/format.h>

extern char** environ;

namespace penumbra::testing {

Expected<ChildProcess> ChildProcess::Spawn(const std::string& exe, const std::vector<std::string>& args,
                                           const std::string& logPath) {
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_addopen(&actions, STDOUT_FILENO, logPath.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
  posix_spawn_file_actions_adddup2(&actions, STDOUT_FILENO, STDERR_FILENO);
  std::vector<std::string> argvStrings;
  argvStrings.push_back(exe);
  argvStrings.insert(argvStrings.end(), args.begin(), args.end());
  std::vector<char*> argv;
  for (auto& a : argvStrings) argv.push_back(a.data());
  argv.push_back(nullptr);
  pid_t pid = -1;
  const int rc = posix_spawn(&pid, exe.c_str(), &actions, nullptr, argv.data(), environ);
  posix_spawn_file_actions_destroy(&actions);
  if (rc != 0) return Fail(fmt::format("cannot start {}: {}", exe, std::strerror(rc)));
  return ChildProcess(pid, logPath);
}

ChildProcess::ChildProcess(ChildProcess&& other) noexcept
    : pid_(other.pid_), exitCode_(other.exitCode_), logPath_(std::move(other.logPath_)) {
  other.pid_ = -1;
}

ChildProcess& ChildProcess::operator=(ChildProcess&& other) noexcept {
  if (this != &other) {
    ChildProcess previous(std::move(*this));  // killed and reaped as it goes out of scope
    pid_ = other.pid_;
    exitCode_ = other.exitCode_;
    logPath_ = std::move(other.logPath_);
    other.pid_ = -1;
  }
  return *this;
}

ChildProcess::~ChildProcess() {
  if (pid_ > 0 && !exitCode_) {
    ::kill(pid_, SIGKILL);
    int status = 0;
    ::waitpid(pid_, &status, 0);
  }
  pid_ = -1;
}

void ChildProcess::Signal(int signal) const {
  if (pid_ > 0 && !exitCode_) ::kill(pid_, signal);
}

bool ChildProcess::Running() { return pid_ > 0 && !WaitExit(std::chrono::milliseconds(0)).has_value(); }

std::optional<int> ChildProcess::WaitExit(std::chrono::milliseconds timeout) {
  if (exitCode_) return exitCode_;
  if (pid_ <= 0) return std::nullopt;
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  while (true) {
    int status = 0;
    const pid_t r = ::waitpid(pid_, &status, WNOHANG);
    if (r == pid_) {
      exitCode_ = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
      return exitCode_;
    }
    if (std::chrono::steady_clock::now() >= deadline) return std::nullopt;
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
}

std::string ChildProcess::LogTail(size_t bytes) const {
  std::ifstream in(logPath_, std::ios::binary);
  std::stringstream s;
  s << in.rdbuf();
  const std::string all = s.str();
  return all.size() > bytes ? all.substr(all.size() - bytes) : all;
}

Expected<uint16_t> WaitForPortFile(ChildProcess& process, const std::string& portFile,
                                   std::chrono::milliseconds timeout) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  while (std::chrono::steady_clock::now() < deadline) {
    std::ifstream in(portFile);
    unsigned port = 0;
    if (in >> port && port > 0 && port < 65536) return uint16_t(port);
    if (!process.Running())
      return Fail(fmt::format("process exited before listening; its log:\n{}", process.LogTail()));
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  return Fail(fmt::format("no port in {} after {} ms; log:\n{}", portFile, timeout.count(), process.LogTail()));
}

double ResidentMegabytes(pid_t pid) {
  std::ifstream status("/proc/" + std::to_string(pid) + "/status");
  std::string line;
  while (std::getline(status, line))
    if (line.rfind("VmRSS:", 0) == 0) return std::stod(line.substr(6)) / 1024.0;  // "VmRSS:  1234 kB"
  return -1.0;
}

std::string MakeTempDir(const std::string& prefix) {
  std::string pattern = (std::filesystem::temp_directory_path() / (prefix + "-XXXXXX")).string();
  if (::mkdtemp(pattern.data()) == nullptr) return std::filesystem::temp_directory_path().string();
  return pattern;
}

std::optional<std::string> FindExecutable(const std::string& name) {
  const char* path = std::getenv("PATH");
  std::stringstream dirs(std::string(path ? path : "") + ":/usr/sbin:/sbin:/usr/bin:/bin");
  for (std::string dir; std::getline(dirs, dir, ':');) {
    const std::filesystem::path candidate = std::filesystem::path(dir) / name;
    if (!dir.empty() && ::access(candidate.c_str(), X_OK) == 0) return candidate.string();
  }
  return std::nullopt;
}

Expected<std::string> RunCommand(const std::string& exe, const std::vector<std::string>& args,
                                 std::chrono::milliseconds timeout) {
  std::string command = exe;
  for (const auto& a : args) command += " " + a;
  const std::string dir = MakeTempDir("penumbra-command");
  std::string output;
  std::optional<int> code;
  {
    auto process = ChildProcess::Spawn(exe, args, dir + "/output");
    if (!process) return process.error();
    code = process->WaitExit(timeout);
    output = process->LogTail(size_t(1) << 24);
  }  // a process still running is killed here
  std::error_code ec;
  std::filesystem::remove_all(dir, ec);
  if (code == 0) return output;
  while (!output.empty() && output.back() == '\n') output.pop_back();
  return Fail(code ? fmt::format("`{}` failed ({}): {}", command, *code, output)
                   : fmt::format("`{}` did not finish in {} ms", command, timeout.count()));
}

}  // namespace penumbra::testing
