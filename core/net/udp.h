// A UDP socket for live mode (dhrbench serve / client / relay): IPv4 and IPv6, non-blocking,
// with a wait on readability that never blocks longer than asked. Only what live mode needs:
// bind, send a datagram to an address, receive one datagram with its sender.
//
// Errors: setting up (resolving, binding, buffer sizes) throws dhr::Error naming the address
// and the system's reason; sending and receiving return outcomes (a full send buffer is a
// dropped datagram, counted by the caller, never a crash or a wait).
#pragma once

#include <netinet/in.h>
#include <sys/socket.h>

#include <cstddef>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

namespace dhr {

// An IPv4 or IPv6 address with a port.
struct Endpoint {
  sockaddr_storage addr{};
  socklen_t len = 0;

  bool valid() const { return len > 0; }
  uint16_t port() const;
  std::string to_string() const;  // "127.0.0.1:4000", "[::1]:4000"
  friend bool operator==(const Endpoint& a, const Endpoint& b);
};

// Resolves "host:port", "[v6]:port" or ":port" / "port" (the wildcard, for binding; `passive`
// true) with getaddrinfo. Throws dhr::Error with the text and getaddrinfo's reason.
Endpoint resolve_endpoint(const std::string& text, bool passive = false);

enum class SendResult : uint8_t { Sent, WouldBlock, Error };
enum class ReceiveResult : uint8_t { Received, Empty, Truncated, Error };

class UdpSocket {
 public:
  // A socket bound to `local` (port 0: the system picks one; see local()). Asks for
  // `buffer_bytes` of kernel send and receive buffer (the kernel may grant less: see
  // receive_buffer_bytes()).
  explicit UdpSocket(const Endpoint& local, int buffer_bytes = 4 << 20);
  ~UdpSocket();
  UdpSocket(const UdpSocket&) = delete;
  UdpSocket& operator=(const UdpSocket&) = delete;

  const Endpoint& local() const { return local_; }
  int fd() const { return fd_; }  // for poll() over several sockets
  int receive_buffer_bytes() const { return rcvbuf_; }

  // Waits at most timeout_ms (0: just checks) until a datagram can be read. Returns false on
  // timeout or when a signal interrupted the wait.
  bool wait_readable(int timeout_ms) const;
  SendResult send_to(std::span<const uint8_t> datagram, const Endpoint& to);
  // Reads one datagram into `buffer` (resized to what arrived; capacity kept). Truncated: it
  // was larger than max_bytes (the rest is lost).
  ReceiveResult receive(std::vector<uint8_t>& buffer, Endpoint& from, size_t max_bytes = 65536);
  const std::string& last_error() const { return last_error_; }

 private:
  int fd_ = -1;
  Endpoint local_;
  int rcvbuf_ = 0;
  std::string last_error_;
};

}  // namespace dhr
