// Tabulated BRDFs (server/models/tabulated_brdf.h): every preset of every model that declares a lobe width,
// tabulated under the default budget, its kernel against the analytic model's kernel on the same pairs in the same
// run (OpenCL fp32, the same launch path), with the table's error against the double reference. The issue 46
// figure: at least 5 times the analytic microcylinder's kernel throughput at T = 32 within 1% relative L1.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <limits>

#include "bench/bench.h"
#include "bench/kernel_runs.h"
#include "bench/report.h"
#include "bench/stats.h"
#include "server/models/material_plan.h"
#include "server/models/registry.h"
#include "server/models/tabulated_brdf.h"

namespace loomlight::bench {
namespace {

// Relative L1 per channel, sum |f - ref| / sum |ref|, over the first ref.size() / 3 pairs; the largest channel.
double RelativeL1(const std::vector<double>& f, const std::vector<double>& ref) {
  double worst = 0;
  for (int c = 0; c < 3; ++c) {
    double diff = 0, sum = 0;
    for (size_t i = c; i < ref.size(); i += 3) {
      diff += std::fabs(f[i] - ref[i]);
      sum += std::fabs(ref[i]);
    }
    worst = std::max(worst, sum > 0 ? diff / sum : 0.0);
  }
  return worst;
}

// The pairs reordered by the table cell of their half vector (kernels/models/tabulated_brdf.h's eta axes), as a
// renderer's tile of pixels under a few lights would send them: neighbouring queries read neighbouring nodes.
Pairs SortedByHalfVectorCell(const Pairs& pairs, const models::TabulationGrid& grid) {
  const size_t n = pairs.size();
  std::vector<uint64_t> key(n);
  for (size_t q = 0; q < n; ++q) {
    const float* a = &pairs.wi[3 * q];
    const float* b = &pairs.wo[3 * q];
    const double hx = a[0] + b[0], hy = a[1] + b[1], hz = a[2] + b[2];
    const auto cell = [](double eta, int nodes) {
      return static_cast<uint64_t>(std::clamp((eta + M_PI / 2) * (nodes - 1) / M_PI, 0.0, nodes - 1.0));
    };
    key[q] = cell(std::atan2(hx, hz), grid.eta_x) * grid.eta_y + cell(std::atan2(hy, hz), grid.eta_y);
  }
  std::vector<size_t> order(n);
  for (size_t q = 0; q < n; ++q) order[q] = q;
  std::stable_sort(order.begin(), order.end(), [&](size_t x, size_t y) { return key[x] < key[y]; });
  Pairs sorted;
  sorted.wi.resize(3 * n);
  sorted.wo.resize(3 * n);
  for (size_t q = 0; q < n; ++q)
    for (int c = 0; c < 3; ++c) {
      sorted.wi[3 * q + c] = pairs.wi[3 * order[q] + c];
      sorted.wo[3 * q + c] = pairs.wo[3 * order[q] + c];
    }
  return sorted;
}

// A launch timed as a whole (wall, BestOfEach) and by its kernel part (LaunchResults::kernel_seconds, the
// fastest of the same runs).
struct Timed {
  double wall = 0, kernel = std::numeric_limits<double>::infinity();
};

}  // namespace

std::string TabulatedSection(runtime::ClRuntime& rt, const Sizes& sizes) {
  std::string error;
  if (!rt.BuildPrograms(models::TabulatedBrdf::KernelRegistry(), &error)) {
    std::fprintf(stderr, "tabulated kernel: %s\n", error.c_str());
    std::exit(1);
  }
  const models::TabulationBudget budget;
  const Pairs pairs = RandomPairs(sizes.kernel_queries, 46);
  const size_t error_queries = std::min<size_t>(sizes.kernel_error_queries, 200000);
  const Pairs error_pairs = pairs.Head(error_queries);

  Table build({"model", "preset", "T", "narrowest lobe (deg)", "grid", "table (MiB)", "build (s)",
               "rel. L1, cosine-weighted", "rel. L1, uniform pairs"},
              2);
  Table speed({"model", "preset", "analytic kernel (q/s)", "tabulated kernel (q/s)", "kernel ratio", "launch ratio",
               "analytic, h-sorted (q/s)", "tabulated, h-sorted (q/s)", "kernel ratio, h-sorted",
               "launch ratio, h-sorted", "figure (>= 5x, <= 1%)"},
              2);
  for (const auto& model : models::Registry::Global().models()) {
    for (const models::PresetSpec& preset : model->presets()) {
      models::PreparedMaterial material;
      material.model = model.get();
      material.values = model->PresetValues(preset);
      if (!(model->NarrowestLobe(material.values) > 0)) break;  // the model declares none: not tabulated
      material.packed = model->Pack(material.values);
      Progress("tabulated: %s %s\n", model->name().c_str(), preset.name.c_str());
      std::shared_ptr<const models::TabulatedBrdf> table;
      const auto start = Clock::now();
      const std::string refused = models::TabulatedBrdf::Build(material, budget, nullptr, &table);
      const double build_seconds = SecondsSince(start);
      const std::string lobe = Fixed(model->NarrowestLobe(material.values) * 180 / M_PI, 1);
      const std::string t = std::to_string(material.packed.uniform);
      if (!refused.empty()) {
        build.Add({model->name(), preset.name, t, lobe, "refused: " + refused, "", "", "", ""});
        continue;
      }
      const models::TabulationGrid& g = table->grid();
      // Accuracy on the benchmark's own (uniform) pairs too: the table's device kernel against the reference.
      const Workload analytic{*model, material.packed, pairs};
      const Workload tabulated{models::TabulatedBrdf::KernelModel(), table->packed(), pairs};
      std::vector<double> ref = Reference(analytic, error_queries, sizes.reference_threads);
      std::vector<double> f_analytic, f_table, f_scratch;
      Timed a, b, a_sorted, b_sorted;
      const Pairs sorted = SortedByHalfVectorCell(pairs, g);
      const Workload analytic_sorted{*model, material.packed, sorted};
      const Workload tabulated_sorted{models::TabulatedBrdf::KernelModel(), table->packed(), sorted};
      const auto run = [&](const Workload& w, std::vector<double>* f, Timed* t) {
        return [&rt, &w, f, t] {
          double k = 0;
          RunOpenCl(rt, false, w, f, &k);
          t->kernel = std::min(t->kernel, k);
        };
      };
      const std::vector<double> wall =
          BestOfEach(sizes.timed_runs, {run(analytic, &f_analytic, &a), run(tabulated, &f_table, &b),
                                        run(analytic_sorted, &f_scratch, &a_sorted),
                                        run(tabulated_sorted, &f_scratch, &b_sorted)});
      a.wall = wall[0], b.wall = wall[1], a_sorted.wall = wall[2], b_sorted.wall = wall[3];
      f_table.resize(ref.size());
      const double uniform_error = RelativeL1(f_table, ref);
      build.Add({model->name(), preset.name, t, lobe,
                 std::to_string(g.eta_x) + " x " + std::to_string(g.eta_y) + " x " + std::to_string(g.psi) +
                     " x " + std::to_string(g.chi),
                 Fixed(table->bytes() / 1048576.0, 1), Fixed(build_seconds, 1), Sci(table->measured_error()),
                 Sci(uniform_error)});
      const double n = static_cast<double>(pairs.size());
      const double kernel_ratio = a.kernel / b.kernel, sorted_ratio = a_sorted.kernel / b_sorted.kernel;
      const bool figure = material.packed.uniform == 32 && kernel_ratio >= 5 && table->measured_error() <= 0.01;
      const bool figure_sorted =
          material.packed.uniform == 32 && sorted_ratio >= 5 && table->measured_error() <= 0.01;
      speed.Add({model->name(), preset.name, Rate(n / a.kernel), Rate(n / b.kernel), Fixed(kernel_ratio, 1),
                 Fixed(a.wall / b.wall, 1), Rate(n / a_sorted.kernel), Rate(n / b_sorted.kernel),
                 Fixed(sorted_ratio, 1), Fixed(a_sorted.wall / b_sorted.wall, 1),
                 std::string(figure ? "yes" : "no") + " / " + (figure_sorted ? "yes" : "no")});
    }
  }
  const std::string method =
      "Every preset of every model that declares its narrowest lobe (Model::NarrowestLobe), at its own parameters "
      "(tangent samples T as the preset sets them), tabulated under the default TabulationBudget (at most " +
      Count(budget.max_bytes) + " bytes, " + Fixed(budget.nodes_per_lobe, 1) + " nodes per lobe width on the h "
      "axes, " + std::to_string(budget.difference_nodes) + " nodes on each of the psi and chi axes; float RGB nodes, "
      "quadrilinear). Errors: relative L1, sum |f_table - f| / sum |f| per channel, the largest channel, against the "
      "double reference: over the " + Count(budget.error_pairs) + " cosine-weighted pairs the table measures itself "
      "on (what the fidelity chooser reads), and over the first " + Count(error_queries) + " of the timed pairs "
      "(the table's OpenCL fp32 kernel). Speed: OpenCL fp32 on PoCL, both kernels on the same " +
      Count(pairs.size()) + " uniformly random pairs over the upper hemisphere in the same run, taking turns, best of " +
      std::to_string(sizes.timed_runs) + " after a warm-up; `kernel` is the launch's kernel part (enqueue to "
      "results readable, LaunchResults::kernel_seconds), `launch` the whole ClRuntime::Run (host lane layout and "
      "copies included, which both pay alike). The same pairs are timed again sorted by the table cell of their half "
      "vector (h-sorted: neighbouring queries read neighbouring nodes, as a renderer's tile under a few lights "
      "sends them; the analytic kernel does not care).";
  return Section("Tabulated BRDFs against the analytic model", method,
                 TableBlock("the grid is eta_x x eta_y x psi x chi nodes "
                            "(kernels/models/tabulated_brdf.h); lower errors are better.",
                            build) +
                     TableBlock("queries/s, higher is better; a ratio is the tabulated kernel's "
                                "throughput over the analytic one's (`launch`: whole launches); `figure` is yes where "
                                "T = 32, the kernel ratio is at least 5 and the cosine-weighted error at most 1% "
                                "(random order / h-sorted).",
                                speed));
}

}  // namespace loomlight::bench
