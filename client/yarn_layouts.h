// The yarn layouts `yarn` and `render` share (docs/fibers.md "Yarn curves" and "Knits"): yarn centre curves read
// from a local CSV file and sent as points, and built-in knits by their stitch, size and spacings.
#pragma once

#include <string>

#include "client/cli.h"
#include "loomlight/v1/loomlight.pb.h"

namespace loomlight::client {

// --curves FILE (with --bspline) into *out; false when --curves is not given. The CSV has one line per control
// point, "yarn,x,y,z[,preset[,radius[,bspline]]]": yarns numbered from 0 without gaps, each yarn's points in file
// order (lines of different yarns may interleave); an optional header (a first line not starting with a number),
// blank lines and lines starting with '#' are skipped. The optional columns hold the yarn's own preset (else
// the request's yarn), radius (else the preset's) and 1 for a B-spline or 0 for a polyline (else --bspline's);
// give them on any of the yarn's lines, the same on every line that gives them. UsageError names FILE:LINE.
bool curves_from_options(const ParsedOptions& options, loomlight::v1::CurveYarnLayout* out);

// --knit jersey|rib, --stitches WALES,COURSES, --wale-spacing S, --course-spacing S into *out; false when --knit
// is not given (the other three then refused). `stitches`: whether --stitches is taken (the BTF tile's are the
// server's).
bool knit_from_options(const ParsedOptions& options, loomlight::v1::KnitYarnLayout* out, bool stitches = true);

// Their options, for a command's option list; `stitches` as above.
OptionList knit_options(bool stitches = true);
OptionList curves_options();

}  // namespace loomlight::client
