// The exact rays (in row order) that trace_visibility_counts / trace_ao_counts (core/trace/trace.h)
// would hand to Embree, without tracing them: benchmarks trace them with a bare Embree loop as
// the ceiling, and tests pin their bits. Embree's ray type: only the trace layer, its tests and
// benchmarks include this header.
#pragma once

#include "core/trace/trace.h"

#include <embree3/rtcore.h>

#include <vector>

namespace dhr {

std::vector<RTCRay> collect_visibility_rays(RtScene& rt, const GBuffer& gbuf, const PassPlan& plan,
                                            const TraceSettings& settings);
std::vector<RTCRay> collect_ao_rays(RtScene& rt, const GBuffer& gbuf, int ao_rays, float ao_radius_m,
                                    const TraceSettings& settings);

}  // namespace dhr
