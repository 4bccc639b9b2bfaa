// Every built-in backend, registered by backends/register_all.cpp. The command line layer
// (experiments/) and the tests hand registries() to the core; dhr_core itself never names a
// backend (docs/architecture.md, "The frame loop").
#pragma once

#include "core/backend/backend.h"

namespace dhr {

// Adds every built-in backend to `r` (one line per backend in register_all.cpp).
void register_all_backends(Registries& r);

// All built-in backends, registered on first use (thread-safe).
const Registries& registries();

}  // namespace dhr
