#include "core/net/udp.h"

#include "core/base/error.h"

#include <arpa/inet.h>
#include <fcntl.h>
#include <netdb.h>
#include <poll.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

namespace dhr {

uint16_t Endpoint::port() const {
  if (addr.ss_family == AF_INET) return ntohs(reinterpret_cast<const sockaddr_in&>(addr).sin_port);
  if (addr.ss_family == AF_INET6) return ntohs(reinterpret_cast<const sockaddr_in6&>(addr).sin6_port);
  return 0;
}

std::string Endpoint::to_string() const {
  char host[INET6_ADDRSTRLEN] = "?";
  if (addr.ss_family == AF_INET) {
    inet_ntop(AF_INET, &reinterpret_cast<const sockaddr_in&>(addr).sin_addr, host, sizeof host);
    return fmt::format("{}:{}", host, port());
  }
  if (addr.ss_family == AF_INET6) {
    inet_ntop(AF_INET6, &reinterpret_cast<const sockaddr_in6&>(addr).sin6_addr, host, sizeof host);
    return fmt::format("[{}]:{}", host, port());
  }
  return "(no address)";
}

bool operator==(const Endpoint& a, const Endpoint& b) {
  if (a.addr.ss_family != b.addr.ss_family || a.port() != b.port()) return false;
  if (a.addr.ss_family == AF_INET)
    return reinterpret_cast<const sockaddr_in&>(a.addr).sin_addr.s_addr ==
           reinterpret_cast<const sockaddr_in&>(b.addr).sin_addr.s_addr;
  if (a.addr.ss_family == AF_INET6)
    return std::memcmp(&reinterpret_cast<const sockaddr_in6&>(a.addr).sin6_addr,
                       &reinterpret_cast<const sockaddr_in6&>(b.addr).sin6_addr, sizeof(in6_addr)) == 0;
  return false;
}

Endpoint resolve_endpoint(const std::string& text, bool passive) {
  std::string host, port;
  if (!text.empty() && text.front() == '[') {
    const size_t close = text.find(']');
    if (close == std::string::npos || close + 1 >= text.size() || text[close + 1] != ':')
      fail("address '{}': expected [IPv6]:port", text);
    host = text.substr(1, close - 1);
    port = text.substr(close + 2);
  } else if (const size_t colon = text.rfind(':'); colon != std::string::npos) {
    host = text.substr(0, colon);
    port = text.substr(colon + 1);
  } else {
    port = text;  // a port alone
  }
  if (port.empty() || port.find_first_not_of("0123456789") != std::string::npos || port.size() > 5 ||
      std::stoi(port) > 65535)
    fail("address '{}': the port must be a number 0..65535 (forms: host:port, [v6]:port, :port, port)", text);
  if (host.empty() && !passive) fail("address '{}': a host is needed (e.g. 127.0.0.1:{})", text, port);
  addrinfo hints{};
  hints.ai_family = AF_UNSPEC;
  hints.ai_socktype = SOCK_DGRAM;
  hints.ai_flags = AI_NUMERICSERV | (passive ? AI_PASSIVE : 0);
  addrinfo* found = nullptr;
  const int rc = getaddrinfo(host.empty() ? nullptr : host.c_str(), port.c_str(), &hints, &found);
  if (rc != 0 || !found) fail("address '{}': cannot resolve: {}", text, gai_strerror(rc));
  // Prefer IPv4 for the wildcard so that ":port" accepts what "127.0.0.1:port" sends.
  const addrinfo* pick = found;
  for (const addrinfo* a = found; a; a = a->ai_next)
    if (a->ai_family == AF_INET) {
      pick = a;
      break;
    }
  Endpoint e;
  std::memcpy(&e.addr, pick->ai_addr, pick->ai_addrlen);
  e.len = socklen_t(pick->ai_addrlen);
  freeaddrinfo(found);
  return e;
}

UdpSocket::UdpSocket(const Endpoint& local, int buffer_bytes) {
  fd_ = ::socket(local.addr.ss_family, SOCK_DGRAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
  if (fd_ < 0) fail("UDP socket for {}: {}", local.to_string(), std::strerror(errno));
  // Ask for large buffers: a pass is sent as a burst of datagrams. The kernel caps the request
  // at net.core.{r,w}mem_max; what it granted is reported.
  setsockopt(fd_, SOL_SOCKET, SO_RCVBUF, &buffer_bytes, sizeof buffer_bytes);
  setsockopt(fd_, SOL_SOCKET, SO_SNDBUF, &buffer_bytes, sizeof buffer_bytes);
  socklen_t optlen = sizeof rcvbuf_;
  getsockopt(fd_, SOL_SOCKET, SO_RCVBUF, &rcvbuf_, &optlen);
  if (::bind(fd_, reinterpret_cast<const sockaddr*>(&local.addr), local.len) != 0) {
    const int err = errno;
    ::close(fd_);
    fail("cannot bind UDP {}: {}{}", local.to_string(), std::strerror(err),
         err == EADDRINUSE ? " (another process uses this port: pick another, or port 0 for any free one)" : "");
  }
  local_.len = sizeof local_.addr;
  getsockname(fd_, reinterpret_cast<sockaddr*>(&local_.addr), &local_.len);
}

UdpSocket::~UdpSocket() {
  if (fd_ >= 0) ::close(fd_);
}

bool UdpSocket::wait_readable(int timeout_ms) const {
  pollfd p{fd_, POLLIN, 0};
  return ::poll(&p, 1, timeout_ms < 0 ? 0 : timeout_ms) > 0 && (p.revents & POLLIN);
}

SendResult UdpSocket::send_to(std::span<const uint8_t> datagram, const Endpoint& to) {
  for (;;) {
    const ssize_t n =
        ::sendto(fd_, datagram.data(), datagram.size(), 0, reinterpret_cast<const sockaddr*>(&to.addr), to.len);
    if (n >= 0) return SendResult::Sent;
    if (errno == EINTR) continue;
    if (errno == EAGAIN || errno == EWOULDBLOCK || errno == ENOBUFS) return SendResult::WouldBlock;
    last_error_ = fmt::format("send to {}: {}", to.to_string(), std::strerror(errno));
    return SendResult::Error;
  }
}

ReceiveResult UdpSocket::receive(std::vector<uint8_t>& buffer, Endpoint& from, size_t max_bytes) {
  buffer.resize(max_bytes);
  from.len = sizeof from.addr;
  for (;;) {
    const ssize_t n =
        ::recvfrom(fd_, buffer.data(), buffer.size(), MSG_TRUNC, reinterpret_cast<sockaddr*>(&from.addr), &from.len);
    if (n >= 0) {
      const bool truncated = size_t(n) > max_bytes;
      buffer.resize(truncated ? max_bytes : size_t(n));
      return truncated ? ReceiveResult::Truncated : ReceiveResult::Received;
    }
    if (errno == EINTR) continue;
    buffer.clear();
    if (errno == EAGAIN || errno == EWOULDBLOCK) return ReceiveResult::Empty;
    // ECONNREFUSED: an ICMP port-unreachable from an earlier send (the peer is gone); the
    // caller sees it as an error it may report, and goes on.
    last_error_ = fmt::format("receive on {}: {}", local_.to_string(), std::strerror(errno));
    return ReceiveResult::Error;
  }
}

}  // namespace dhr
