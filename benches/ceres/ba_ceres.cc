// The peer of `geostride ba` in benches/ba_vs_ceres.rs: one BAL problem solved by Ceres Solver
// (SPARSE_SCHUR, points eliminated first, Ceres's default tolerances), printed as one JSON line.
//
//   ba_ceres FILE [THREADS] [MAX_ITERATIONS]
//
// Built by the benchmark against Debian's libceres-dev. The camera is BAL's: angle-axis
// rotation, translation, f, k1, k2; p = -P.xy / P.z; u = f (1 + k1 |p|^2 + k2 |p|^4) p.

#include <ceres/ceres.h>
#include <ceres/rotation.h>

#include <cstdio>
#include <fstream>
#include <iostream>
#include <memory>
#include <string>
#include <vector>

namespace {

struct BalResidual {
  BalResidual(double x, double y) : observed_x(x), observed_y(y) {}

  template <typename T>
  bool operator()(const T* const camera, const T* const point, T* residual) const {
    T p[3];
    ceres::AngleAxisRotatePoint(camera, point, p);
    for (int i = 0; i < 3; ++i) p[i] += camera[3 + i];
    const T xn = -p[0] / p[2];
    const T yn = -p[1] / p[2];
    const T r2 = xn * xn + yn * yn;
    const T d = T(1.0) + camera[7] * r2 + camera[8] * r2 * r2;
    residual[0] = camera[6] * d * xn - T(observed_x);
    residual[1] = camera[6] * d * yn - T(observed_y);
    return true;
  }

  double observed_x;
  double observed_y;
};

bool Fail(const std::string& why) {
  std::cerr << "ba_ceres: " << why << std::endl;
  return false;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2) {
    std::cerr << "usage: ba_ceres FILE [THREADS] [MAX_ITERATIONS]" << std::endl;
    return 2;
  }
  const int threads = argc > 2 ? std::stoi(argv[2]) : 2;
  const int max_iterations = argc > 3 ? std::stoi(argv[3]) : 50;
  std::ifstream in(argv[1]);
  int num_cameras = 0, num_points = 0, num_observations = 0;
  if (!(in >> num_cameras >> num_points >> num_observations)) {
    Fail(std::string("cannot read the header of ") + argv[1]);
    return 2;
  }
  std::vector<int> camera_of(num_observations), point_of(num_observations);
  std::vector<double> xy(2 * num_observations);
  for (int k = 0; k < num_observations; ++k) {
    if (!(in >> camera_of[k] >> point_of[k] >> xy[2 * k] >> xy[2 * k + 1])) {
      Fail("observation " + std::to_string(k));
      return 2;
    }
  }
  std::vector<double> cameras(9 * num_cameras), points(3 * num_points);
  for (double& v : cameras) {
    if (!(in >> v)) return Fail("cameras"), 2;
  }
  for (double& v : points) {
    if (!(in >> v)) return Fail("points"), 2;
  }

  ceres::Problem problem;
  for (int k = 0; k < num_observations; ++k) {
    auto* cost = new ceres::AutoDiffCostFunction<BalResidual, 2, 9, 3>(
        new BalResidual(xy[2 * k], xy[2 * k + 1]));
    problem.AddResidualBlock(cost, nullptr, &cameras[9 * camera_of[k]], &points[3 * point_of[k]]);
  }
  ceres::Solver::Options options;
  options.linear_solver_type = ceres::SPARSE_SCHUR;
  options.num_threads = threads;
  options.max_num_iterations = max_iterations;
  auto ordering = std::make_shared<ceres::ParameterBlockOrdering>();
  for (int j = 0; j < num_points; ++j) ordering->AddElementToGroup(&points[3 * j], 0);
  for (int i = 0; i < num_cameras; ++i) ordering->AddElementToGroup(&cameras[9 * i], 1);
  options.linear_solver_ordering = ordering;
  options.logging_type = ceres::SILENT;

  ceres::Solver::Summary summary;
  ceres::Solve(options, &problem, &summary);
  std::printf(
      "{\"initial_cost\": %.17g, \"final_cost\": %.17g, \"iterations\": %d, "
      "\"successful_steps\": %d, \"seconds\": %.6f, \"termination\": \"%s\", "
      "\"linear_solver\": \"%s\", \"threads\": %d}\n",
      summary.initial_cost, summary.final_cost, static_cast<int>(summary.iterations.size()) - 1,
      summary.num_successful_steps, summary.total_time_in_seconds,
      ceres::TerminationTypeToString(summary.termination_type),
      ceres::LinearSolverTypeToString(summary.linear_solver_type_used), summary.num_threads_used);
  return summary.IsSolutionUsable() ? 0 : 1;
}
