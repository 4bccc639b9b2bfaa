// A per-thread workspace kept between calls, so that a stage's large scratch buffers reuse their
// memory frame after frame instead of taking fresh pages (whose first touch costs about 0.45 s
// per GB on the 2-vCPU machines: docs/performance.md).
#pragma once

#include <memory>

namespace dhr {

// Leases this thread's workspace of type W for one call. A call made while the thread's
// workspace is busy -- a nested call from a task this thread picked up while waiting in its own
// parallel loop -- gets a fresh one, freed when the lease ends. What a lease hands out keeps the
// contents of its last use: a caller sizes and overwrites what it reads.
template <class W>
class WorkspaceLease {
 public:
  WorkspaceLease() {
    static thread_local Slot cached;
    if (cached.busy) {
      fresh_ = std::make_unique<W>();
      ws_ = fresh_.get();
    } else {
      cached.busy = true;
      slot_ = &cached;
      ws_ = &cached.workspace;
    }
  }
  ~WorkspaceLease() {
    if (slot_) slot_->busy = false;
  }
  WorkspaceLease(const WorkspaceLease&) = delete;
  WorkspaceLease& operator=(const WorkspaceLease&) = delete;
  W& operator*() { return *ws_; }
  W* operator->() { return ws_; }

 private:
  struct Slot {
    bool busy = false;
    W workspace;
  };
  Slot* slot_ = nullptr;
  std::unique_ptr<W> fresh_;
  W* ws_ = nullptr;
};

}  // namespace dhr
