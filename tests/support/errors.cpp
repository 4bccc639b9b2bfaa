#include "core/base/error.h"
#include "core/base/process.h"
#include "tests/support.h"

namespace dhr::test {

std::string error_of(const std::function<void()>& f) {
  try {
    f();
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

int run_program(const std::string& program, const std::vector<std::string>& args, std::string& log) {
  std::vector<std::string> argv{program};
  argv.insert(argv.end(), args.begin(), args.end());
  ProcessResult r = run_process(argv, {.err = ProcessOptions::Err::WithOut});
  log = std::move(r.out);
  return r.exit_code;
}

}  // namespace dhr::test
