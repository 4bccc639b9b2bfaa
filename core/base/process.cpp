#include "core/base/process.h"

#include "core/base/error.h"

#include <fcntl.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <cerrno>

extern char** environ;

namespace dhr {

ProcessResult run_process(const std::vector<std::string>& argv, const ProcessOptions& options) {
  const bool capture_out = options.capture_out || options.err == ProcessOptions::Err::WithOut;
  const size_t max_out = options.max_out;
  if (argv.empty()) fail("run_process: no program given");
  std::vector<char*> args;
  for (const auto& a : argv) args.push_back(const_cast<char*>(a.c_str()));
  args.push_back(nullptr);

  int pipe_fd[2] = {-1, -1};
  if (capture_out && pipe2(pipe_fd, O_CLOEXEC) != 0) fail("run_process: cannot create a pipe for {}", argv[0]);
  posix_spawn_file_actions_t fa;
  posix_spawn_file_actions_init(&fa);
  posix_spawn_file_actions_addopen(&fa, 0, "/dev/null", O_RDONLY, 0);
  if (capture_out) posix_spawn_file_actions_adddup2(&fa, pipe_fd[1], 1);
  if (options.err == ProcessOptions::Err::Discard) posix_spawn_file_actions_addopen(&fa, 2, "/dev/null", O_WRONLY, 0);
  if (options.err == ProcessOptions::Err::WithOut) posix_spawn_file_actions_adddup2(&fa, pipe_fd[1], 2);
  pid_t pid = -1;
  // glibc's posix_spawnp reports a program that cannot be executed as its return value.
  const int rc = posix_spawnp(&pid, argv[0].c_str(), &fa, nullptr, args.data(), environ);
  posix_spawn_file_actions_destroy(&fa);
  ProcessResult r;
  if (capture_out) close(pipe_fd[1]);
  if (rc != 0) {
    if (capture_out) close(pipe_fd[0]);
    return r;
  }
  r.started = true;
  if (capture_out) {
    std::array<char, 4096> buf{};
    for (;;) {
      const ssize_t n = read(pipe_fd[0], buf.data(), buf.size());
      if (n < 0 && errno == EINTR) continue;
      if (n <= 0) break;
      if (r.out.size() < max_out) r.out.append(buf.data(), std::min(size_t(n), max_out - r.out.size()));
    }
    close(pipe_fd[0]);
  }
  int status = 0;
  while (waitpid(pid, &status, 0) < 0)
    if (errno != EINTR) return r;
  if (WIFEXITED(status))
    r.exit_code = WEXITSTATUS(status);
  else if (WIFSIGNALED(status))
    r.signal = WTERMSIG(status);
  return r;
}

}  // namespace dhr
