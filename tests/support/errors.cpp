#include "core/error.h"
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

}  // namespace dhr::test
