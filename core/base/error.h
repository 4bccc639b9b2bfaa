// Error policy (after Falcor's): assertions for programmer mistakes, dhr::Error for bad input
// and failed library calls (a message that names the file, key or value and what is valid),
// return values for expected outcomes handled on the spot (a packet lost on the link).
#pragma once

#include <fmt/format.h>

#include <stdexcept>
#include <string>

namespace dhr {

class Error : public std::runtime_error {
 public:
  explicit Error(const std::string& message) : std::runtime_error(message) {}
};

template <class... Args>
[[noreturn]] void fail(fmt::format_string<Args...> format, Args&&... args) {
  throw Error(fmt::format(format, std::forward<Args>(args)...));
}

}  // namespace dhr
