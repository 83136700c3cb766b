// The material options shared by every command that evaluates (eval, plot).
#pragma once

#include <string>

#include "client/cli.h"
#include "loomlight/v1/loomlight.pb.h"

namespace loomlight::client {

// The synopsis of the material options; a macro so that command synopses can embed it in their literals.
#define LOOMLIGHT_MATERIAL_SYNOPSIS "(--preset NAME | --model NAME | --btf ASSET) [--param NAME=V1[,V2...]]... [--fp64]"

// --preset, --model, --btf, --param (repeatable), --fp64.
const OptionList& material_options();

// An EvaluateRequest carrying the material and precision from the options, without directions yet.
// The server checks names, counts and ranges; the client only checks the syntax.
loomlight::v1::EvaluateRequest material_request(const ParsedOptions& options);

// "NAME=V1[,V2...]" as a Param; a UsageError naming `option` when malformed.
loomlight::v1::Param parse_param(const std::string& text, const std::string& option);

// --yarn PRESET and --yarn-param NAME=V (repeatable) into *yarn: the procedural yarn of `yarn` and of
// Render's fiber scenes.
void yarn_from_options(const ParsedOptions& options, loomlight::v1::Yarn* yarn);

// The bytes of a file on the client's machine (sent to the server as data); a UsageError naming `option`
// when it cannot be read.
std::string read_local_file(const std::string& path, const std::string& option);

// Writes the bytes to a file on the client's machine; std::runtime_error when it cannot.
void write_local_file(const std::string& path, const std::string& bytes);

// A short human name of the material, e.g. "silk_shot" or "microcylinder (eta=1.46)", for titles.
std::string material_label(const loomlight::v1::Material& material);

}  // namespace loomlight::client
