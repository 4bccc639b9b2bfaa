// none: no prediction. The newest received buffer is shown as it is, in screen space, however
// old it is (the paper's Fig. 6, "without prediction").
//
// Parameters: none.   Example: {"name": "none"}
#include "core/backend/backend.h"

namespace dhr {
namespace {

class NonePredictor final : public Predictor {
 public:
  PredictStats predict(const PredictInput& in, PassBuffer& out) override {
    out = in.received;
    PredictStats s;
    s.pixels = uint64_t(in.dst.width()) * uint64_t(in.dst.height());
    return s;
  }
};

}  // namespace

PredictorEntry make_none_predictor() {
  return {"none", "no prediction: show the newest received buffer as it is", {}, [](const Params&) {
            return std::make_unique<NonePredictor>();
          }};
}

}  // namespace dhr
