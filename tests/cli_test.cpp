// The command lines of the real binaries, parsed by CLI11: every command's and the server's --help lists its
// options; "--name=value" means "--name value"; an unknown option or a bad value exits 2 naming the option; the
// client's --server defaults to $LOOMLIGHT_SERVER.
#include <sys/wait.h>
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <fstream>
#include <iterator>
#include <set>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

#include "tests/testing.h"

namespace loomlight {
namespace {

struct Result {
  int exit_code = -1;
  std::string output;  // stdout and stderr
};

// Runs `command_line` through sh, with LOOMLIGHT_SERVER unset unless `server_env` names a target.
Result Run(const std::string& command_line, const std::string& server_env = "") {
  const std::string env = server_env.empty() ? "env -u LOOMLIGHT_SERVER " : "env LOOMLIGHT_SERVER=" + server_env + " ";
  Result result;
  FILE* pipe = popen((env + command_line + " 2>&1").c_str(), "r");
  char buffer[4096];
  while (pipe && std::fgets(buffer, sizeof buffer, pipe)) result.output += buffer;
  const int status = pipe ? pclose(pipe) : -1;
  result.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return result;
}

Result Client(const std::string& args, const std::string& server_env = "") {
  return Run(std::string(LOOMLIGHT_CLIENT_BINARY) + " " + args, server_env);
}

// The server with `args` and --help: it exits 2 when it refuses `args`, else prints its help and exits 0 (it never
// starts serving).
Result ServerHelp(const std::string& args) {
  return Run(std::string(LOOMLIGHT_SERVER_BINARY) + " " + args + " --help");
}

bool Lists(const std::string& help, const std::string& option) {
  return help.find("  " + option + " ") != std::string::npos || help.find("  " + option + "\n") != std::string::npos;
}

TEST(Cli, ServerHelpListsItsOptionsWithTheirHelp) {
  const Result help = ServerHelp("");
  ASSERT_EQ(help.exit_code, 0) << help.output;
  EXPECT_NE(help.output.find("usage: loomlight-server"), std::string::npos) << help.output;
  const std::vector<std::pair<std::string, std::string>> options = {
      {"--address HOST:PORT", "listen address"},
      {"--tls-cert FILE", "PEM certificate chain"},
      {"--tokens FILE", "bearer token"},
      {"--allow-plaintext-remote", "plaintext on an address other than loopback"},
      {"--trusted-proxy ADDR[/BITS]", "X-Forwarded-For"},
      {"--queue-policy PRIORITY:KEY=VALUE[,KEY=VALUE...]", "one priority's queue"},
      {"--no-batching", "one request per launch"},
      {"--data-dir DIR", "BTF assets live under DIR/btf"},
      {"--mesh-store-mb N", "all uploaded meshes' files together"},
      {"--mesh-cache-mb N", "parsed meshes kept for renders"},
      {"--memory-budget-mb N", "bytes all calls' buffers may hold"},
      {"--max-long-calls-per-client N", "of them, one client's"},
      {"--keepalive-seconds N", "ping a connection"},
      {"--keepalive-timeout-seconds N", "pinged connection"},
      {"--max-connection-age-grace-seconds N", "may finish within"},
      {"--max-health-watches-per-client N", "one client's"},
      {"--max-call-seconds [PRIORITY:]N", "a call's deadline"},
      {"--stall-write-seconds N", "reads nothing"},
      {"--shutdown-grace SECONDS", "in-flight calls may finish"},
  };
  for (const auto& [option, text] : options) {
    const size_t at = help.output.find("  " + option);
    ASSERT_NE(at, std::string::npos) << option << "\n" << help.output;
    // The help text follows the option (on its line, or the next when the option is long).
    const size_t text_at = help.output.find(text, at);
    EXPECT_NE(text_at, std::string::npos) << option;
    EXPECT_LT(text_at, help.output.find("\n  -", at + 3)) << option << ": its help text is not its own";
  }
}

TEST(Cli, EveryCommandHelpListsItsOptions) {
  const std::vector<std::pair<std::string, std::vector<std::string>>> commands = {
      {"models", {"--verbose"}},
      {"scenes", {}},
      {"eval", {"--preset", "--param", "--wi", "--wo", "--wi-deg", "--wo-deg", "--csv", "--ambient", "--verbose"}},
      {"sample", {"--preset", "--wo", "--count", "--seed", "--uv", "--out"}},
      {"plot", {"--preset", "--incidence", "--plane-phi", "--samples", "--size", "--view", "--full-circle"}},
      {"slice", {"--preset", "--wi", "--wo-deg", "--size", "--region", "--spp", "--format", "--out"}},
      {"tab", {"--preset", "--grid", "--dims", "--incidence", "--phi-h-samples", "--format", "--out"}},
      {"render", {"--preset", "--scene", "--size", "--spp", "--light", "--env", "--error-target", "--out", "--knit",
                  "--stitches", "--curves", "--bspline"}},
      {"batch", {"--csv", "--jobs", "--retries", "--backoff", "--log"}},
      {"yarn", {"--yarn", "--weave", "--weave-wif", "--max-fibers", "--points-per-twist", "--out", "--curves",
                "--bspline", "--knit", "--stitches", "--wale-spacing", "--course-spacing"}},
      {"btf", {}},
      {"btf create", {"--grid", "--resolution", "--components", "--target-psnr", "--replace", "--fibers", "--knit",
                      "--wale-spacing"}},
      {"btf list", {"--plot"}},
      {"btf delete", {}},
      {"btf images", {"--grid", "--format", "--exposure"}},
      {"btf upload", {"--grid", "--value-scale", "--replace"}},
      {"mesh", {}},
      {"mesh upload", {"--name", "--format"}},
      {"mesh list", {}},
      {"mesh delete", {}},
      {"health", {"--service", "--alive"}},
  };
  for (const auto& [command, options] : commands) {
    for (const std::string& form : {command + " --help", "help " + command}) {
      const Result help = Client(form);
      ASSERT_EQ(help.exit_code, 0) << form << "\n" << help.output;
      EXPECT_EQ(help.output.rfind("usage: loomlight " + command, 0), 0) << form << "\n" << help.output;
      for (const std::string& option : options) EXPECT_TRUE(Lists(help.output, option)) << form << ": " << option;
      // The connection options, with --server's environment variable.
      for (const char* option : {"--server", "--timeout", "--tls-ca", "--token-file", "-h,--help"})
        EXPECT_TRUE(Lists(help.output, option)) << form << ": " << option;
      EXPECT_NE(help.output.find("(Env:LOOMLIGHT_SERVER)"), std::string::npos) << form;
    }
  }
  const Result help = Client("--help");
  ASSERT_EQ(help.exit_code, 0) << help.output;
  for (const char* command : {"models", "eval", "render", "btf", "health", "help"})
    EXPECT_NE(help.output.find(std::string("\n  ") + command + " "), std::string::npos) << command;
  EXPECT_TRUE(Lists(help.output, "--server"));
}

TEST(Cli, ClientRefusalsExitTwoNamingTheOption) {
  // Refused as the command line is read, so also when it asks for --help.
  const std::vector<std::pair<std::string, std::string>> parse_refusals = {
      {"eval --preset velvet --no-such-option=1 --wi 0,0,1 --wo 0,0,1", "unknown option '--no-such-option'"},
      {"--no-such-option models", "unknown option '--no-such-option'"},
      {"btf create --no-such-option x --preset velvet", "unknown option '--no-such-option'"},
      {"health --alive=yes", "--alive: takes no value"},
  };
  for (const auto& [args, message] : parse_refusals) {
    for (const std::string& line : {args, args + " --help"}) {
      const Result result = Client(line);
      EXPECT_EQ(result.exit_code, 2) << line << "\n" << result.output;
      EXPECT_NE(result.output.find("error: " + message), std::string::npos) << line << "\n" << result.output;
    }
  }
  // Refused by the command's own checks.
  const std::vector<std::pair<std::string, std::string>> refusals = {
      {"health --service", "--service: 1 required"},
      {"health --timeout soon", "bad number 'soon' in --timeout"},
      {"plot --preset velvet --size 5 --out x.png", "--size must be an integer in [100, 8000], got '5'"},
      {"models surplus", "unexpected argument 'surplus'"},
      {"btf delete", "missing arguments"},
      {"btf", "'btf' needs a command"},
      {"btf rename", "unknown command 'btf rename'"},
      {"yarn --knit wool --out x.pbrt", "--knit: expected jersey or rib, got 'wool'"},
      {"yarn --stitches 4,4 --out x.pbrt", "--stitches, --wale-spacing and --course-spacing need --knit"},
      {"yarn --knit jersey --stitches 4 --out x.pbrt", "--stitches needs WALES,COURSES"},
      {"yarn --knit jersey --length 2 --out x.pbrt", "give one layout"},
      {"yarn --bspline --out x.pbrt", "--bspline is for --curves"},
      {"btf create k --preset cotton --knit jersey", "--yarn, --weave, --spacing, --crimp, --knit and --rays are for --fibers"},
      {"no-such-command", "unknown command 'no-such-command'"},
  };
  for (const auto& [args, message] : refusals) {
    const Result result = Client(args);
    EXPECT_EQ(result.exit_code, 2) << args << "\n" << result.output;
    EXPECT_NE(result.output.find("error: " + message), std::string::npos) << args << "\n" << result.output;
  }
}

TEST(Cli, ServerRefusalsExitTwoNamingTheOption) {
  const std::vector<std::pair<std::string, std::string>> refusals = {
      {"--no-such-option=1", "unknown option '--no-such-option'"},
      {"--max-long-calls=0", "--max-long-calls: must be at least 1"},
      {"--grpc-memory-mb abc", "--grpc-memory-mb: takes a whole number, got 'abc'"},
      {"--fold-cache-mb -1", "--fold-cache-mb: takes a whole number, got '-1'"},
      {"--memory-budget-mb 16777217", "--memory-budget-mb: takes 1..16777216 MiB"},
      {"--no-batching=yes", "--no-batching: takes no value"},
      {"--max-call-seconds interactive:x", "--max-call-seconds takes N, interactive:N or bulk:N"},
      {"--queue-policy bulk:timeout_ms=x", "--queue-policy: 'timeout_ms=x' is not KEY=NUMBER"},
      {"--trusted-proxy 10.0.0.0/8 --trusted-proxy proxy.example",
       "--trusted-proxy: 'proxy.example' is not ADDRESS or ADDRESS/BITS"},
      {"stray", "unexpected argument 'stray'"},
  };
  for (const auto& [args, message] : refusals) {
    const Result result = ServerHelp(args);
    EXPECT_EQ(result.exit_code, 2) << args << "\n" << result.output;
    EXPECT_NE(result.output.find("error: " + message), std::string::npos) << args << "\n" << result.output;
  }
  // Both forms of every kind of option are accepted.
  for (const char* args :
       {"--address=127.0.0.1:0 --max-long-calls=4 --memory-budget-mb=512 --max-call-seconds=bulk:60 "
        "--trusted-proxy=10.0.0.0/8 --queue-policy=bulk:timeout_ms=5 --no-batching",
        "--address 127.0.0.1:0 --max-long-calls 4 --memory-budget-mb 512 --max-call-seconds bulk:60 "
        "--trusted-proxy 10.0.0.0/8 --queue-policy bulk:timeout_ms=5 --no-batching"}) {
    const Result result = ServerHelp(args);
    EXPECT_EQ(result.exit_code, 0) << args << "\n" << result.output;
  }
}

class CliServer : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    server_ = new testing::ServerProcess();
    ASSERT_GT(server_->port(), 0);
  }
  static void TearDownTestSuite() {
    delete server_;
    server_ = nullptr;
  }
  static testing::ServerProcess* server_;
};
testing::ServerProcess* CliServer::server_ = nullptr;

TEST_F(CliServer, EqualsAndSpaceFormsGiveTheSameResult) {
  const std::string address = server_->address();
  const Result spaced = Client("--server " + address + " eval --preset velvet --wi-deg 30,0 --wo-deg 45,180 "
                               "--wi 0,0,1 --wo 0.6,0,0.8 --timeout 60");
  const Result equals = Client("--server=" + address + " eval --preset=velvet --wi-deg=30,0 --wo-deg=45,180 "
                               "--wi=0,0,1 --wo=0.6,0,0.8 --timeout=60");
  ASSERT_EQ(spaced.exit_code, 0) << spaced.output;
  ASSERT_EQ(equals.exit_code, 0) << equals.output;
  EXPECT_EQ(equals.output, spaced.output);
  // Two queries, in the order given: header and two rows, the degrees' pair first.
  ASSERT_EQ(std::count(spaced.output.begin(), spaced.output.end(), '\n'), 3) << spaced.output;
  EXPECT_NE(spaced.output.find("\n0,0,1,0.6"), std::string::npos) << spaced.output;
  EXPECT_LT(spaced.output.find("\n0.5,"), spaced.output.find("\n0,0,1,")) << spaced.output;
}

// --ambient sends wo alone (QUANTITY_AMBIENT): the client counted its queries from wi, found none, and refused
// the server's answer ("3 values for 0 queries").
TEST_F(CliServer, AmbientPrintsOneRowPerWo) {
  const Result ambient = Client("--server " + server_->address() +
                                " eval --preset cotton --ambient --wo 0,0,1 --wo-deg 60,90 --timeout 60");
  ASSERT_EQ(ambient.exit_code, 0) << ambient.output;
  std::istringstream lines(ambient.output);
  std::string line;
  std::getline(lines, line);
  EXPECT_EQ(line, "wox,woy,woz,r,g,b");
  int rows = 0;
  while (std::getline(lines, line)) {
    std::vector<double> values;
    std::istringstream cells(line);
    for (std::string cell; std::getline(cells, cell, ',');) values.push_back(std::stod(cell));
    ASSERT_EQ(values.size(), 6u) << line;
    for (int c = 3; c < 6; ++c) EXPECT_TRUE(std::isfinite(values[c]) && values[c] > 0) << line;
    ++rows;
  }
  EXPECT_EQ(rows, 2) << ambient.output;
  EXPECT_NE(ambient.output.find("\n0,0,1,"), std::string::npos) << ambient.output;
}

// The knit and curve layouts end to end: `yarn` writes one curve shape per fiber for a knit and for curves from a
// CSV; `render` with --knit or --curves picks the scene that shows them and renders it.
TEST_F(CliServer, KnitsAndCurvesFromTheCommandLine) {
  const std::string dir = ::testing::TempDir(), server = "--server " + server_->address() + " ";
  const Result knit = Client(server + "yarn --knit rib --stitches 4,3 --footprint 0.02 --out " + dir + "/cli_knit.pbrt");
  ASSERT_EQ(knit.exit_code, 0) << knit.output;
  EXPECT_NE(knit.output.find(" fibers, "), std::string::npos) << knit.output;
  {
    std::ofstream csv(dir + "/cli_curves.csv");
    // Yarn 0 a B-spline by --bspline, yarn 1 a polyline by its column.
    csv << "yarn,x,y,z,preset,radius,bspline\n0,0,0,0\n0,0.3,0,0.5\n0,0,0,1\n0,0.3,0,1.5\n1,1,0,0,,,0\n1,1,0,1\n";
  }
  const Result curves =
      Client(server + "yarn --curves " + dir + "/cli_curves.csv --bspline --footprint 0.02 --out " + dir + "/cli_curves.pbrt");
  ASSERT_EQ(curves.exit_code, 0) << curves.output;
  std::ifstream pbrt(dir + "/cli_curves.pbrt");
  std::string line;
  std::set<std::string> yarns;
  while (std::getline(pbrt, line))
    if (line.rfind("# ", 0) == 0 && line.find(" yarn ") != std::string::npos)
      yarns.insert(line.substr(line.find(" yarn ") + 6, 2));
  EXPECT_EQ(yarns, (std::set<std::string>{"0 ", "1 "}));

  const Result knit_render = Client(server + "render --preset cotton --knit jersey --stitches 3,3 --size 24x16 --spp 1 "
                                    "--fiber-detail lod --out " + dir + "/cli_knit.png");
  ASSERT_EQ(knit_render.exit_code, 0) << knit_render.output;
  EXPECT_NE(knit_render.output.find("knit patch (fibers)"), std::string::npos) << knit_render.output;
  const Result curve_render = Client(server + "render --preset cotton --curves " + dir + "/cli_curves.csv --bspline --size 24x16 "
                                     "--spp 1 --fiber-detail lod --out " + dir + "/cli_curves.png");
  ASSERT_EQ(curve_render.exit_code, 0) << curve_render.output;
  EXPECT_NE(curve_render.output.find("yarn curves (fibers)"), std::string::npos) << curve_render.output;
  // The server refuses a knit on a scene that does not lay one out, naming the field.
  const Result refused = Client(server + "render --preset cotton --scene yarn --knit jersey --size 24x16 --out " + dir +
                                "/cli_refused.png");
  EXPECT_EQ(refused.exit_code, 1) << refused.output;
  EXPECT_NE(refused.output.find("knit: only for"), std::string::npos) << refused.output;
}

// A WIF draft's colours reach the woven model through --param-file pattern.wif=FILE unchanged: the gingham
// (tests/data/wif/gingham.wif, read here: warp and weft threads 1-4 white 255,255,255, 5-8 blue 32,64,160) slices
// white where white crosses white (u and v below 1/2) and blue where blue crosses blue; its BRDF (eval) and a
// swatch render are blue on the whole, where the preset's own yarns are not.
TEST_F(CliServer, WifDraftColoursReachEvalSliceAndRender) {
  const std::string dir = ::testing::TempDir(), server = "--server " + server_->address() + " ";
  const std::string draft = " --preset cotton_twill --param-file pattern.wif=" + std::string(LOOMLIGHT_SOURCE_DIR) +
                            "/tests/data/wif/gingham.wif ";
  const Result slice = Client(server + "slice" + draft + "--wi-deg 30,0 --wo-deg 20,180 --size 16x16 --out " + dir +
                              "/cli_gingham.exr");
  ASSERT_EQ(slice.exit_code, 0) << slice.output;
  std::ifstream file(dir + "/cli_gingham.exr", std::ios::binary);
  const std::string bytes((std::istreambuf_iterator<char>(file)), std::istreambuf_iterator<char>());
  const testing::DecodedImage image = testing::DecodeImage(bytes, "x.exr");
  ASSERT_EQ(image.width, 16);
  // Sums of blue over red in a quadrant (the top row is v = 1).
  const auto blue_over_red = [&](int x0, int y0) {
    double r = 0, b = 0;
    for (int y = y0; y < y0 + 8; ++y)
      for (int x = x0; x < x0 + 8; ++x) {
        const size_t at = (size_t(y) * 16 + size_t(x)) * size_t(image.channels);
        r += image.pixels[at], b += image.pixels[at + 2];
      }
    return b / r;
  };
  EXPECT_NEAR(blue_over_red(0, 8), 1.0, 0.1);  // white on white: u, v < 1/2
  EXPECT_GT(blue_over_red(8, 0), 3.0);         // 160 / 32 in sRGB, more in linear
  const auto last_rgb = [](const std::string& output) {
    const std::string row = output.substr(output.rfind('\n', output.size() - 2) + 1);
    std::vector<double> values;
    std::istringstream cells(row);
    for (std::string cell; std::getline(cells, cell, ',');) values.push_back(std::stod(cell));
    return std::vector<double>(values.end() - 3, values.end());
  };
  const Result plain = Client(server + "eval --preset cotton_twill --wi-deg 30,0 --wo-deg 20,180");
  const Result gingham = Client(server + "eval" + draft + "--wi-deg 30,0 --wo-deg 20,180");
  ASSERT_EQ(plain.exit_code, 0) << plain.output;
  ASSERT_EQ(gingham.exit_code, 0) << gingham.output;
  EXPECT_LT(last_rgb(plain.output)[2], last_rgb(plain.output)[0]);
  EXPECT_GT(last_rgb(gingham.output)[2], 1.2 * last_rgb(gingham.output)[0]);
  const Result render = Client(server + "render" + draft + "--scene swatch --size 24x16 --spp 1 --format exr --out " +
                               dir + "/cli_gingham_swatch.exr");
  ASSERT_EQ(render.exit_code, 0) << render.output;
  std::ifstream swatch_file(dir + "/cli_gingham_swatch.exr", std::ios::binary);
  const testing::DecodedImage swatch = testing::DecodeImage(
      std::string((std::istreambuf_iterator<char>(swatch_file)), std::istreambuf_iterator<char>()), "x.exr");
  double r = 0, b = 0;
  for (size_t at = 0; at + 2 < swatch.pixels.size(); at += size_t(swatch.channels))
    r += swatch.pixels[at], b += swatch.pixels[at + 2];
  EXPECT_GT(b, 1.2 * r);
}

TEST_F(CliServer, ServerComesFromTheEnvironmentWhenNotGiven) {
  const std::string address = server_->address();
  const std::string closed = "127.0.0.1:" + std::to_string(testing::ClosedLoopbackPort());
  const Result models = Client("models", address);
  ASSERT_EQ(models.exit_code, 0) << models.output;
  EXPECT_NE(models.output.find("\nmodel "), std::string::npos) << models.output;
  EXPECT_NE(models.output.find("velvet"), std::string::npos) << models.output;
  for (const char* command : {"health", "scenes", "btf list", "eval --preset velvet --wi 0,0,1 --wo 0,0,1"})
    EXPECT_EQ(Client(command, address).exit_code, 0) << command;
  // The variable is what the client used: pointing it at a closed port fails the call ...
  const Result nobody = Client("health --timeout 10", closed);
  EXPECT_EQ(nobody.exit_code, 1) << nobody.output;
  EXPECT_NE(nobody.output.find("UNAVAILABLE"), std::string::npos) << nobody.output;
  // ... and --server, before or after the command, overrides it.
  EXPECT_EQ(Client("--server " + address + " models", closed).exit_code, 0);
  EXPECT_EQ(Client("models --server=" + address, closed).exit_code, 0);
}

}  // namespace
}  // namespace loomlight
