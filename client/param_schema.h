// Parameter schemas as `loomlight models` and `loomlight scenes` print them (client/models.cpp).
#pragma once

#include <iosfwd>

#include "client/rpc.h"

namespace loomlight::client {

// "  parameters:" and one aligned row per parameter (name, type, unit, range, count, default, description).
void print_parameters(std::ostream& out, const google::protobuf::RepeatedPtrField<v1::ParamSchema>& params);

}  // namespace loomlight::client
