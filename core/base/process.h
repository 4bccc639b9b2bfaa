// Child processes from an argument vector, never through a shell: no word of the vector is
// parsed, so a name with quotes, $(...), backticks, spaces or newlines reaches the child as
// one argument, as it was written.
#pragma once

#include <string>
#include <vector>

namespace dhr {

struct ProcessResult {
  bool started = false;  // false: the program could not be run (not found, not executable)
  int exit_code = -1;    // the child's exit status; -1 when it did not exit normally
  int signal = 0;        // the signal that ended it, else 0
  std::string out;       // its standard output, when captured
  bool ok() const { return started && exit_code == 0; }
};

struct ProcessOptions {
  bool capture_out = false;  // standard output into ProcessResult::out (else inherited)
  enum class Err { Inherit, Discard, WithOut } err = Err::Inherit;  // WithOut: into out as well
  size_t max_out = size_t(1) << 20;  // bytes of output kept; the rest is read and dropped
};

// Runs argv[0] (a path, or a name looked up in PATH) with argv and waits for it. Standard input
// is /dev/null. Throws dhr::Error only for an empty argv or when no pipe can be made.
ProcessResult run_process(const std::vector<std::string>& argv, const ProcessOptions& options = {});

}  // namespace dhr
