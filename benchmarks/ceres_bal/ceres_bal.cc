// A small BAL bundle adjuster on Ceres, used by benchmarks/bundle_adjustment.py as the C++
// reference: autodiff BAL reprojection cost (angle-axis, translation, f, k1, k2; p = -P/P_z;
// radial distortion 1 + k1 r^2 + k2 r^4), Levenberg-Marquardt, one thread.
//
// usage: ceres_bal FILE [SPARSE_SCHUR|DENSE_SCHUR] [max_iterations]
// prints one JSON line: initial_cost, final_cost, iterations, successful_steps,
// unsuccessful_steps, solver_time_s, total_time_s, termination.
#include <chrono>
#include <cstdio>
#include <string>
#include <vector>

#include "ceres/ceres.h"
#include "ceres/rotation.h"

namespace {

struct BalResidual {
  BalResidual(double u, double v) : u_(u), v_(v) {}

  template <typename T>
  bool operator()(const T* cam, const T* X, T* r) const {
    T P[3];
    ceres::AngleAxisRotatePoint(cam, X, P);  // R X
    for (int i = 0; i < 3; ++i) P[i] += cam[3 + i];
    const T px = -P[0] / P[2];
    const T py = -P[1] / P[2];
    const T r2 = px * px + py * py;
    const T scale = cam[6] * (T(1.0) + r2 * (cam[7] + cam[8] * r2));
    r[0] = scale * px - T(u_);
    r[1] = scale * py - T(v_);
    return true;
  }

  double u_, v_;
};

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2) {
    std::fprintf(stderr, "usage: %s FILE [SPARSE_SCHUR|DENSE_SCHUR] [max_iterations]\n", argv[0]);
    return 2;
  }
  const auto t0 = std::chrono::steady_clock::now();
  FILE* fh = std::fopen(argv[1], "r");
  if (!fh) {
    std::fprintf(stderr, "cannot open %s\n", argv[1]);
    return 2;
  }
  int nc = 0, np = 0, no = 0;
  if (std::fscanf(fh, "%d %d %d", &nc, &np, &no) != 3) return 3;
  std::vector<int> ci(no), pi(no);
  std::vector<double> uv(2 * no), params(9 * nc + 3 * np);
  for (int k = 0; k < no; ++k)
    if (std::fscanf(fh, "%d %d %lf %lf", &ci[k], &pi[k], &uv[2 * k], &uv[2 * k + 1]) != 4)
      return 3;
  for (auto& v : params)
    if (std::fscanf(fh, "%lf", &v) != 1) return 3;
  std::fclose(fh);

  double* cams = params.data();
  double* pts = params.data() + 9 * nc;
  ceres::Problem problem;
  for (int k = 0; k < no; ++k) {
    auto* cost = new ceres::AutoDiffCostFunction<BalResidual, 2, 9, 3>(
        new BalResidual(uv[2 * k], uv[2 * k + 1]));
    problem.AddResidualBlock(cost, nullptr, cams + 9 * ci[k], pts + 3 * pi[k]);
  }
  ceres::Solver::Options options;
  const std::string solver = argc > 2 ? argv[2] : "SPARSE_SCHUR";
  options.linear_solver_type =
      solver == "DENSE_SCHUR" ? ceres::DENSE_SCHUR : ceres::SPARSE_SCHUR;
  options.max_num_iterations = argc > 3 ? std::atoi(argv[3]) : 100;
  options.num_threads = 1;
  options.minimizer_progress_to_stdout = false;
  options.logging_type = ceres::SILENT;
  ceres::Solver::Summary summary;
  ceres::Solve(options, &problem, &summary);
  const double total =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  std::printf(
      "{\"solver\": \"%s\", \"initial_cost\": %.10f, \"final_cost\": %.10f, \"iterations\": %d, "
      "\"successful_steps\": %d, \"unsuccessful_steps\": %d, \"solver_time_s\": %.6f, "
      "\"total_time_s\": %.6f, \"termination\": \"%s\"}\n",
      solver.c_str(), summary.initial_cost, summary.final_cost,
      static_cast<int>(summary.iterations.size()) - 1, summary.num_successful_steps,
      summary.num_unsuccessful_steps, summary.total_time_in_seconds, total,
      ceres::TerminationTypeToString(summary.termination_type));
  return 0;
}
