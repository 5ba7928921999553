#include <doctest/doctest.h>

#include <Eigen/SVD>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <random>
#include <vector>

#include "sim/pbd_kernels.h"

using namespace dvx;
using Eigen::Matrix3d;
using Eigen::Quaterniond;
using Eigen::Vector3d;

namespace {

// Fixed-seed generator whose doubles do not depend on the standard library's distributions.
struct Rng {
  std::mt19937_64 engine;
  explicit Rng(uint64_t seed) : engine(seed) {}
  double uniform(double lo, double hi) { return lo + (hi - lo) * double(engine() >> 11) * 0x1.0p-53; }
  Vector3d vec(double lo, double hi) { return Vector3d(uniform(lo, hi), uniform(lo, hi), uniform(lo, hi)); }
  // Uniform random rotation (rejection sampling in the 4-ball).
  Quaterniond rotation() {
    for (;;) {
      Eigen::Vector4d v(uniform(-1, 1), uniform(-1, 1), uniform(-1, 1), uniform(-1, 1));
      const double n = v.norm();
      if (n > 0.1 && n < 1.0) return Quaterniond(v / n);
    }
  }
  Vector3d unit() {
    for (;;) {
      const Vector3d v = vec(-1, 1);
      const double n = v.norm();
      if (n > 0.1 && n < 1.0) return v / n;
    }
  }
  // 0 .. n - 1 in a random order (Fisher-Yates).
  std::vector<uint32_t> order(uint32_t n) {
    std::vector<uint32_t> o(n);
    for (uint32_t i = 0; i < n; ++i) o[i] = i;
    for (uint32_t i = n > 0 ? n - 1 : 0; i > 0; --i) std::swap(o[i], o[uint32_t(uniform(0, i + 0.999))]);
    return o;
  }
};

// |a - b| relative to the larger magnitude (doctest's Approx adds 1 to the scale, which makes it an
// absolute test for small values such as a spring's stretch).
double relative_error(double a, double b) {
  const double m = std::max(std::fabs(a), std::fabs(b));
  return m > 0 ? std::fabs(a - b) / m : 0.0;
}

// The kernel paths this CPU can run (the baseline always; AVX2 and AVX-512 where it has them): the
// tests compare each with the scalar path, so every path is checked on a machine that has it.
std::vector<KernelIsa> kernel_paths() {
  std::vector<KernelIsa> paths = {KernelIsa::kBaseline};
  if (kernel_isa() >= KernelIsa::kAvx2) paths.push_back(KernelIsa::kAvx2);
  if (kernel_isa() >= KernelIsa::kAvx512) paths.push_back(KernelIsa::kAvx512);
  return paths;
}

bool finite_unit(const Quaterniond& q) { return q.coeffs().allFinite() && std::fabs(q.norm() - 1.0) < 1e-12; }

// Largest entry difference of the two rotation matrices (q and -q are the same rotation).
double rotation_distance(const Quaterniond& a, const Quaterniond& b) {
  return (a.toRotationMatrix() - b.toRotationMatrix()).cwiseAbs().maxCoeff();
}

// f(R) = tr(R^T A), and its maximum over rotations (the sum of singular values, the smallest one
// negated when det A < 0).
double trace_rt_a(const Quaterniond& q, const Matrix3d& a) { return (q.toRotationMatrix().transpose() * a).trace(); }
double best_trace(const Matrix3d& a) {
  Eigen::JacobiSVD<Matrix3d> svd(a, Eigen::ComputeFullU | Eigen::ComputeFullV);
  const Vector3d s = svd.singularValues();
  const double d = (svd.matrixU() * svd.matrixV().transpose()).determinant();
  return s[0] + s[1] + (d > 0 ? s[2] : -s[2]);
}

// Symmetric positive stretch with eigenvalues in [lo, hi] along random axes.
Matrix3d random_stretch(Rng& rng, double lo, double hi) {
  const Matrix3d q = rng.rotation().toRotationMatrix();
  return q * rng.vec(lo, hi).asDiagonal() * q.transpose();
}

// --- particle helpers: positions are double[3] per particle in a flat array ---
Vector3d get(const std::vector<double>& x, uint32_t i) { return Vector3d(x[3 * i], x[3 * i + 1], x[3 * i + 2]); }
void set(std::vector<double>& x, uint32_t i, const Vector3d& p) {
  for (int k = 0; k < 3; ++k) x[3 * i + k] = p[k];
}

// A cube cluster: 8 corners (corner c = bits (x, y, z)) of side `side` at `origin`, stored in a larger
// particle array at scattered indices, so the kernels must go through `indices`.
struct Cube {
  static constexpr int kCount = 8;
  std::vector<double> x;         // (12 x 3) particle positions; 4 particles are not in the cluster
  std::vector<double> inv_mass;  // (12)
  std::array<uint32_t, 8> indices{{7, 2, 11, 0, 5, 9, 3, 10}};
  std::array<double, 24> rest{};  // (8 x 3) rest positions in cluster order
  double side = 0.1;

  explicit Cube(const Vector3d& origin = Vector3d(0.3, -0.2, 0.5)) : x(36, 0.0), inv_mass(12, 1.0) {
    for (int c = 0; c < kCount; ++c) {
      const Vector3d r = origin + side * Vector3d(c & 1, (c >> 1) & 1, (c >> 2) & 1);
      for (int k = 0; k < 3; ++k) rest[3 * c + k] = r[k];
      set(x, indices[c], r);
    }
    // Particles outside the cluster: somewhere else, must never move.
    for (uint32_t i : {1u, 4u, 6u, 8u}) set(x, i, Vector3d(5.0 + i, -3.0, 2.0));
  }
  Vector3d rest_of(int c) const { return Vector3d(rest[3 * c], rest[3 * c + 1], rest[3 * c + 2]); }
  Vector3d pos(int c) const { return get(x, indices[c]); }
  Vector3d rest_centre() const {
    Vector3d s = Vector3d::Zero();
    for (int c = 0; c < kCount; ++c) s += rest_of(c);
    return s / kCount;
  }
  // Map every corner through p -> f(rest position).
  template <class F>
  void place(F f) {
    for (int c = 0; c < kCount; ++c) set(x, indices[c], f(rest_of(c)));
  }
  // Signed volume from the mean edge vectors along the three cube axes.
  double volume() const {
    Vector3d e[3] = {Vector3d::Zero(), Vector3d::Zero(), Vector3d::Zero()};
    for (int c = 0; c < kCount; ++c)
      for (int axis = 0; axis < 3; ++axis)
        if (!(c & (1 << axis))) e[axis] += 0.25 * (pos(c | (1 << axis)) - pos(c));
    return e[0].dot(e[1].cross(e[2]));
  }
  bool finite() const {
    for (double v : x)
      if (!std::isfinite(v)) return false;
    return true;
  }
  void solve(double stiffness, Quaterniond& rotation) {
    solve_shape_matching(x.data(), inv_mass.data(), indices.data(), rest.data(), kCount, stiffness, rotation);
  }
};

// Hanging spring: particle 0 fixed at the origin, particle 1 (mass 1) below it under gravity. XPBD
// steps (predict, `iterations` solves with lambda reset per step, velocity update, light damping);
// returns the final stretch.
double hanging_spring_stretch(double compliance, int iterations, int steps) {
  const double dt = 1.0 / 60.0, rest = 1.0, gravity = -9.81;
  std::vector<double> x = {0, 0, 0, 0, -rest, 0};
  const std::vector<double> inv_mass = {0.0, 1.0};
  Vector3d v = Vector3d::Zero();
  for (int s = 0; s < steps; ++s) {
    const Vector3d old = get(x, 1);
    v.y() += gravity * dt;
    set(x, 1, old + dt * v);
    double lambda = 0.0;
    for (int it = 0; it < iterations; ++it)
      solve_distance(x.data(), inv_mass.data(), 0, 1, rest, compliance, dt, lambda);
    v = 0.98 * (get(x, 1) - old) / dt;
  }
  return get(x, 1).norm() - rest;
}

}  // namespace

TEST_SUITE("pbd_kernels") {
  // ---------------------------------------------------------------- extract_rotation
  TEST_CASE("extract_rotation: A = R S gives R to 1e-9 from the identity within the default iterations") {
    Rng rng(11);
    for (int trial = 0; trial < 1000; ++trial) {
      Quaterniond r = rng.rotation();
      // Every 10th: exactly half a turn, where the identity start sits on a saddle of tr(R^T A).
      if (trial % 10 == 0) r = Quaterniond(Eigen::AngleAxisd(M_PI, rng.unit()));
      const Matrix3d s = random_stretch(rng, 0.3, 3.0);
      const Quaterniond q = extract_rotation(r.toRotationMatrix() * s, Quaterniond::Identity());
      REQUIRE(finite_unit(q));
      CHECK(rotation_distance(q, r) < 1e-9);
    }
  }

  TEST_CASE("extract_rotation: warm start from the answer needs 1-2 iterations") {
    Rng rng(12);
    for (int trial = 0; trial < 200; ++trial) {
      const Quaterniond r = rng.rotation();
      const Matrix3d s = random_stretch(rng, 0.5, 2.0);
      // From the exact answer, one iteration leaves it where it is.
      const Quaterniond same = extract_rotation(r.toRotationMatrix() * s, r, 1);
      CHECK(rotation_distance(same, r) < 1e-12);
      // The next step's matrix (rotated by ~1e-3 rad, stretch changed by ~1e-3) from the previous answer:
      // two iterations reach 1e-9 (a method converging only linearly would not).
      const Quaterniond r2 = Quaterniond(Eigen::AngleAxisd(1e-3, rng.unit())) * r;
      const Matrix3d s2 = s + 1e-3 * random_stretch(rng, -1.0, 1.0);
      const Quaterniond next = extract_rotation(r2.toRotationMatrix() * s2, r, 2);
      CHECK(rotation_distance(next, r2) < 1e-9);
    }
  }

  TEST_CASE("extract_rotation: zero or non-finite A leaves q unchanged, no NaN") {
    const Quaterniond q = Quaterniond(Eigen::AngleAxisd(0.7, Vector3d(1, 2, 3).normalized()));
    const Quaterniond zero = extract_rotation(Matrix3d::Zero(), q);
    CHECK((zero.coeffs() - q.coeffs()).cwiseAbs().maxCoeff() < 1e-15);
    Matrix3d bad = Matrix3d::Identity();
    bad(1, 2) = std::nan("");
    const Quaterniond nan_a = extract_rotation(bad, q);
    CHECK((nan_a.coeffs() - q.coeffs()).cwiseAbs().maxCoeff() < 1e-15);
    // A broken warm start is replaced by the identity, not propagated.
    const Quaterniond from_zero = extract_rotation(Matrix3d::Identity(), Quaterniond(0, 0, 0, 0));
    CHECK(finite_unit(from_zero));
    CHECK(rotation_distance(from_zero, Quaterniond::Identity()) < 1e-12);
  }

  TEST_CASE("extract_rotation: rank-1 and rank-2 (flattened) A give finite unit rotations that fit A") {
    Rng rng(13);
    for (int trial = 0; trial < 200; ++trial) {
      const Quaterniond r = rng.rotation();
      const Quaterniond start = trial % 2 ? rng.rotation() : Quaterniond::Identity();
      // All points on a plane: A = R diag(s1, s2, 0) V^T has a unique nearest rotation R V^T.
      const Matrix3d v = rng.rotation().toRotationMatrix();
      const Vector3d s(rng.uniform(0.2, 2.0), rng.uniform(0.2, 2.0), 0.0);
      const Matrix3d plane = r.toRotationMatrix() * s.asDiagonal() * v.transpose();
      const Quaterniond q2 = extract_rotation(plane, start);
      REQUIRE(finite_unit(q2));
      CHECK(rotation_distance(q2, Quaterniond(r.toRotationMatrix() * v.transpose())) < 1e-9);
      // All points on a line: A = a b^T; any rotation taking b to a's direction is a best fit.
      const Vector3d a = rng.vec(-1, 1), b = rng.vec(-1, 1);
      const Matrix3d line = a * b.transpose();
      const Quaterniond q1 = extract_rotation(line, start);
      REQUIRE(finite_unit(q1));
      CHECK((q1.toRotationMatrix() * b.normalized() - a.normalized()).norm() < 1e-9);
      CHECK(relative_error(trace_rt_a(q1, line), best_trace(line)) < 1e-12);
    }
  }

  TEST_CASE("extract_rotation: inverted A (det < 0) converges to a fixed answer and stays there") {
    Rng rng(14);
    for (int trial = 0; trial < 100; ++trial) {
      const Matrix3d r = rng.rotation().toRotationMatrix();
      // Mirrored cube (all singular values equal: a flat family of best rotations) and a generic
      // inverted stretch (unique best rotation R, flipping the shortest axis).
      const Matrix3d mirrored = r * Vector3d(1, 1, -1).asDiagonal();
      const Matrix3d squashed = r * Vector3d(1.5, 0.8, -0.3).asDiagonal();
      for (const Matrix3d& a : {mirrored, squashed}) {
        Quaterniond q = trial % 2 ? rng.rotation() : Quaterniond::Identity();
        double largest_change = 0.0;
        for (int call = 0; call < 100; ++call) {
          const Quaterniond next = extract_rotation(a, q);
          REQUIRE(finite_unit(next));
          if (call > 0) largest_change = std::max(largest_change, (next.coeffs() - q.coeffs()).norm());
          q = next;
        }
        CHECK(largest_change < 1e-9);
        CHECK(relative_error(trace_rt_a(q, a), best_trace(a)) < 1e-12);
      }
      CHECK(rotation_distance(extract_rotation(squashed, Quaterniond::Identity()), Quaterniond(r)) < 1e-9);
    }
  }

  TEST_CASE("extract_rotation: 1000 random matrices in [-1, 1] give finite unit best-fit rotations") {
    Rng rng(15);
    for (int trial = 0; trial < 1000; ++trial) {
      Matrix3d a;
      for (int k = 0; k < 9; ++k) a(k) = rng.uniform(-1, 1);
      const Quaterniond q = extract_rotation(a, trial % 2 ? rng.rotation() : Quaterniond::Identity());
      REQUIRE(finite_unit(q));
      // Ascent on tr(R^T A) finds its global maximum (it has no other local maximum on SO(3)).
      CHECK(relative_error(trace_rt_a(q, a), best_trace(a)) < 1e-9);
    }
  }

  // ---------------------------------------------------------------- solve_distance
  TEST_CASE("solve_distance: a free particle tied to a fixed one reaches the rest length") {
    std::vector<double> x = {0.1, 0.2, 0.3, 1.4, -0.5, 0.9};
    const std::vector<double> inv_mass = {0.0, 2.0};
    const Vector3d fixed = get(x, 0);
    const double rest = 0.5;
    double lambda = 0.0;
    solve_distance(x.data(), inv_mass.data(), 0, 1, rest, 0.0, 1.0 / 60.0, lambda);
    // Hard constraint: one solve is exact; the fixed particle has not moved at all.
    CHECK(relative_error((get(x, 1) - get(x, 0)).norm(), rest) < 1e-12);
    CHECK(get(x, 0) == fixed);
    // Soft constraint, lambda accumulated over iterations, same step: converges to C = -alpha~ lambda.
    x = {0.1, 0.2, 0.3, 1.4, -0.5, 0.9};
    const double compliance = 1e-4, dt = 1.0 / 60.0;
    lambda = 0.0;
    for (int it = 0; it < 200; ++it) solve_distance(x.data(), inv_mass.data(), 0, 1, rest, compliance, dt, lambda);
    const double c = (get(x, 1) - get(x, 0)).norm() - rest;
    CHECK(relative_error(c, -compliance / (dt * dt) * lambda) < 1e-9);
    CHECK(get(x, 0) == fixed);
  }

  TEST_CASE("solve_distance: two free particles meet the rest length and keep their mass centre") {
    std::vector<double> x = {0.0, 0.0, 0.0, 1.0, 2.0, -1.0};
    const std::vector<double> inv_mass = {1.0, 3.0};
    const auto centre = [&]() -> Vector3d {
      return (get(x, 0) / inv_mass[0] + get(x, 1) / inv_mass[1]) / (1.0 / inv_mass[0] + 1.0 / inv_mass[1]);
    };
    const Vector3d c0 = centre();
    double lambda = 0.0;
    solve_distance(x.data(), inv_mass.data(), 0, 1, 0.7, 0.0, 0.01, lambda);
    CHECK(relative_error((get(x, 1) - get(x, 0)).norm(), 0.7) < 1e-12);
    CHECK((centre() - c0).norm() < 1e-12);
  }

  TEST_CASE("solve_distance: XPBD stretch under a load does not depend on the iteration count") {
    // Equilibrium stretch of a spring of stiffness 1/compliance under m g.
    const double compliance = 1e-3, expected = compliance * 9.81;
    const double one = hanging_spring_stretch(compliance, 1, 3000);
    const double twenty = hanging_spring_stretch(compliance, 20, 3000);
    CHECK(relative_error(one, expected) < 0.03);
    CHECK(relative_error(twenty, expected) < 0.03);
    CHECK(relative_error(twenty, one) < 0.03);
    // Zero compliance is a hard constraint: no stretch, whatever the iteration count.
    CHECK(std::fabs(hanging_spring_stretch(0.0, 1, 500)) < 1e-12);
    CHECK(std::fabs(hanging_spring_stretch(0.0, 20, 500)) < 1e-12);
  }

  TEST_CASE("solve_distance: coincident particles and two anchored particles are left alone") {
    std::vector<double> x = {0.5, 0.5, 0.5, 0.5, 0.5, 0.5};
    const std::vector<double> x0 = x;
    std::vector<double> inv_mass = {1.0, 1.0};
    double lambda = 0.25;
    solve_distance(x.data(), inv_mass.data(), 0, 1, 1.0, 0.0, 0.01, lambda);
    CHECK(x == x0);
    CHECK(lambda == 0.25);
    solve_distance(x.data(), inv_mass.data(), 0, 1, 1.0, 1e-3, 0.01, lambda);
    CHECK(x == x0);
    // Both anchored, stretched: nothing moves, for hard and soft constraints.
    x = {0, 0, 0, 2, 0, 0};
    const std::vector<double> x1 = x;
    inv_mass = {0.0, 0.0};
    solve_distance(x.data(), inv_mass.data(), 0, 1, 1.0, 0.0, 0.01, lambda);
    solve_distance(x.data(), inv_mass.data(), 0, 1, 1.0, 1e-3, 0.01, lambda);
    CHECK(x == x1);
    for (double v : x) CHECK(std::isfinite(v));
    CHECK(std::isfinite(lambda));
  }

  // ---------------------------------------------------------------- shape matching
  TEST_CASE("solve_shape_matching: a rigidly moved cube does not move") {
    Rng rng(21);
    for (int trial = 0; trial < 50; ++trial) {
      Cube cube;
      const Quaterniond r = trial % 5 == 0 ? Quaterniond(Eigen::AngleAxisd(M_PI, rng.unit())) : rng.rotation();
      const Vector3d t = rng.vec(-2, 2), c0 = cube.rest_centre();
      for (int c = 0; c < Cube::kCount; ++c) cube.inv_mass[cube.indices[c]] = rng.uniform(0.5, 2.0);
      cube.place([&](const Vector3d& p) { return Vector3d(r * (p - c0) + c0 + t); });
      const std::vector<double> before = cube.x;
      Quaterniond rotation = Quaterniond::Identity();
      cube.solve(1.0, rotation);
      double moved = 0.0;
      for (size_t k = 0; k < before.size(); ++k) moved = std::max(moved, std::fabs(cube.x[k] - before[k]));
      CHECK(moved < 1e-12);
      CHECK(rotation_distance(rotation, r) < 1e-9);
    }
  }

  TEST_CASE("solve_shape_matching: a deformed cube with stiffness 1 snaps to a rigid copy of the rest shape") {
    Rng rng(22);
    for (int trial = 0; trial < 50; ++trial) {
      Cube cube;
      for (int c = 0; c < Cube::kCount; ++c) cube.inv_mass[cube.indices[c]] = rng.uniform(0.5, 2.0);
      const Matrix3d r = rng.rotation().toRotationMatrix();
      cube.place([&](const Vector3d& p) { return Vector3d(r * p + rng.vec(-0.04, 0.04)); });
      // Momentum: without anchors the mass centre must not move.
      const auto centre = [&] {
        Vector3d s = Vector3d::Zero();
        double m = 0.0;
        for (int c = 0; c < Cube::kCount; ++c) {
          const double mc = 1.0 / cube.inv_mass[cube.indices[c]];
          s += mc * cube.pos(c);
          m += mc;
        }
        return Vector3d(s / m);
      };
      const Vector3d centre_before = centre();
      Quaterniond rotation = Quaterniond::Identity();
      cube.solve(1.0, rotation);
      for (int a = 0; a < Cube::kCount; ++a)
        for (int b = a + 1; b < Cube::kCount; ++b)
          CHECK(std::fabs((cube.pos(a) - cube.pos(b)).norm() - (cube.rest_of(a) - cube.rest_of(b)).norm()) < 1e-9);
      CHECK(relative_error(cube.volume(), std::pow(cube.side, 3)) < 1e-9);
      CHECK((centre() - centre_before).norm() < 1e-12);
    }
  }

  TEST_CASE("solve_shape_matching: flattened and inverted cubes recover a finite, positive volume") {
    Rng rng(23);
    const double rest_volume = std::pow(0.1, 3);
    for (int trial = 0; trial < 30; ++trial) {
      const Matrix3d r = rng.rotation().toRotationMatrix();
      const Vector3d t = rng.vec(-1, 1);
      // Flattened onto a plane, squashed onto a line, mirrored through a plane, and inverted with an
      // anisotropic stretch; each seen from a random rotation.
      const Matrix3d deformations[] = {Vector3d(1, 1, 0).asDiagonal(), Vector3d(1, 0, 0).asDiagonal(),
                                       Vector3d(1, 1, -1).asDiagonal(), Vector3d(1.3, 0.8, -0.6).asDiagonal()};
      for (const Matrix3d& d : deformations) {
        Cube cube;
        const Vector3d c0 = cube.rest_centre();
        cube.place([&](const Vector3d& p) { return Vector3d(r * d * (p - c0) + c0 + t); });
        CHECK(cube.volume() <= 1e-18);
        Quaterniond rotation = Quaterniond::Identity();
        for (int application = 0; application < 6; ++application) cube.solve(0.5, rotation);
        REQUIRE(cube.finite());
        CHECK(finite_unit(rotation));
        CHECK(cube.volume() > 0.9 * rest_volume);
      }
    }
  }

  TEST_CASE("solve_shape_matching: anchored particles never move and pin the cluster") {
    Rng rng(24);
    // Corners 0, 3, 5 anchored at their rest positions; the rest of the cube pulled 0.05 away, perturbed.
    const int anchors[] = {0, 3, 5};
    Cube cube;
    for (int c : anchors) cube.inv_mass[cube.indices[c]] = 0.0;
    cube.place([&](const Vector3d& p) { return Vector3d(p + Vector3d(0.05, 0, 0) + rng.vec(-0.01, 0.01)); });
    for (int c : anchors) set(cube.x, cube.indices[c], cube.rest_of(c));
    const Cube start = cube;
    // One full-stiffness application puts the cube back where the anchors hold it (with the anchors
    // weighted like the others the centre would move only 5/8 of the way: ~0.02 off).
    Quaterniond rotation = Quaterniond::Identity();
    cube.solve(1.0, rotation);
    for (int c = 0; c < Cube::kCount; ++c) CHECK((cube.pos(c) - cube.rest_of(c)).norm() < 1e-5);
    // Repeated soft applications from the deformed state: anchors bit-for-bit where they were.
    cube = start;
    rotation = Quaterniond::Identity();
    for (int application = 0; application < 20; ++application) {
      cube.solve(0.7, rotation);
      for (int c : anchors) CHECK(cube.pos(c) == start.pos(c));
    }
    // Particles outside the cluster were never touched.
    CHECK(get(cube.x, 1) == Vector3d(6.0, -3.0, 2.0));
  }

  TEST_CASE("shape_matching_corrections: equals the in-place displacement, anchors get zero") {
    Rng rng(25);
    for (int trial = 0; trial < 50; ++trial) {
      Cube cube;
      for (int c = 0; c < Cube::kCount; ++c)
        cube.inv_mass[cube.indices[c]] = c == trial % 8 ? 0.0 : rng.uniform(0.5, 2.0);
      const Matrix3d r = rng.rotation().toRotationMatrix();
      cube.place([&](const Vector3d& p) { return Vector3d(r * p + rng.vec(-0.05, 0.05)); });
      const std::vector<double> before = cube.x;
      const Quaterniond start = rng.rotation();
      Quaterniond rotation_a = start, rotation_b = start;
      std::array<double, 24> delta;
      delta.fill(1.0);
      shape_matching_corrections(cube.x.data(), cube.inv_mass.data(), cube.indices.data(), cube.rest.data(),
                                 Cube::kCount, 0.6, rotation_a, delta.data());
      CHECK(cube.x == before);  // corrections do not move anything
      cube.solve(0.6, rotation_b);
      CHECK(rotation_a.coeffs() == rotation_b.coeffs());
      for (int c = 0; c < Cube::kCount; ++c)
        for (int k = 0; k < 3; ++k) {
          const uint32_t i = cube.indices[c];
          CHECK(cube.x[3 * i + k] == before[3 * i + k] + delta[3 * c + k]);
          if (cube.inv_mass[i] == 0.0) CHECK(delta[3 * c + k] == 0.0);
        }
    }
  }

  // The solver's path (rest frame built once, solves from it) against a plain reference: mass
  // centres, A, its polar rotation by SVD, goals c + R (r_i - c0), with anchored particles weighing
  // 1e6 x the free mean. Warm-started from the SVD rotation, the kernel's few rotation iterations
  // must land on it: goals agree to 1e-9 of the cube's size.
  TEST_CASE("solve_shape_matching from a prebuilt rest frame equals a reference implementation") {
    Rng rng(41);
    for (int trial = 0; trial < 200; ++trial) {
      Cube cube;
      for (int c = 0; c < Cube::kCount; ++c)
        cube.inv_mass[cube.indices[c]] = trial % 3 == 0 && c == trial % 8 ? 0.0 : rng.uniform(0.5, 2.0);
      const Matrix3d deform = rng.rotation().toRotationMatrix() * random_stretch(rng, 0.7, 1.3);
      const Vector3d shift = rng.vec(-2, 2);
      cube.place([&](const Vector3d& p) { return Vector3d(deform * p + shift + rng.vec(-0.05, 0.05)); });
      // Reference.
      double free_mass = 0.0;
      int free_count = 0;
      for (int c = 0; c < Cube::kCount; ++c) {
        const double w = cube.inv_mass[cube.indices[c]];
        if (w > 0.0) free_mass += 1.0 / w, ++free_count;
      }
      std::array<double, 8> m;
      double total = 0.0;
      Vector3d cx = Vector3d::Zero(), cr = Vector3d::Zero();
      for (int c = 0; c < Cube::kCount; ++c) {
        const double w = cube.inv_mass[cube.indices[c]];
        m[c] = w > 0.0 ? 1.0 / w : 1e6 * free_mass / free_count;
        cx += m[c] * cube.pos(c);
        cr += m[c] * cube.rest_of(c);
        total += m[c];
      }
      cx /= total;
      cr /= total;
      Matrix3d a = Matrix3d::Zero();
      for (int c = 0; c < Cube::kCount; ++c) a += m[c] * (cube.pos(c) - cx) * (cube.rest_of(c) - cr).transpose();
      Eigen::JacobiSVD<Matrix3d> svd(a, Eigen::ComputeFullU | Eigen::ComputeFullV);
      const Matrix3d polar = svd.matrixU() * svd.matrixV().transpose();
      REQUIRE(polar.determinant() > 0.0);
      std::array<Vector3d, 8> goal;
      for (int c = 0; c < Cube::kCount; ++c) goal[c] = cx + polar * (cube.rest_of(c) - cr);
      // The kernel.
      ShapeRest rest;
      REQUIRE(shape_matching_rest(cube.inv_mass.data(), cube.indices.data(), cube.rest.data(), Cube::kCount, rest));
      Quaterniond rotation(polar);
      const std::vector<double> before = cube.x;
      solve_shape_matching(cube.x.data(), cube.indices.data(), rest, 1.0, rotation);
      for (int c = 0; c < Cube::kCount; ++c) {
        const uint32_t i = cube.indices[c];
        const Vector3d expected = cube.inv_mass[i] > 0.0 ? goal[c] : get(before, i);
        CHECK((cube.pos(c) - expected).norm() < 1e-9);
      }
    }
  }

  // The solver's blocks (kShapeLanes clusters of one colour in vector lanes) against the scalar
  // path, cluster by cluster, on every kernel path: the same IEEE operations per lane, so the same
  // bits. Clusters: mildly deformed (the rotation step's usual case), inverted, flattened, collapsed
  // to a point, with an anchor, and warm starts that are not unit (the last four take
  // extract_rotation's fallback); blocks of 1 to 8 lanes (so a half of four alone, both halves, and
  // a second half with repeated lanes); repeated solves, so the warm starts evolve as in the solver.
  TEST_CASE("solve_shape_block equals the scalar solve_shape_matching lane by lane, also on hard clusters") {
    const int kClusters = kShapeLanes;
    for (const KernelIsa isa : kernel_paths()) {
      CAPTURE(int(isa));
      Rng rng(47);
      for (int trial = 0; trial < 120; ++trial) {
        // kClusters cubes side by side in one particle array (no shared particle).
        const int lanes = 1 + trial % kShapeLanes;
        std::vector<double> x(3 * 8 * kClusters), rest(3 * 8 * kClusters), inv_mass(8 * kClusters);
        std::array<std::array<uint32_t, 8>, kClusters> indices;
        for (int cl = 0; cl < lanes; ++cl) {
          const int kind = (trial + cl) % 6;
          const Matrix3d r = rng.rotation().toRotationMatrix();
          Matrix3d d = random_stretch(rng, 0.8, 1.2);
          if (kind == 1) d = Vector3d(1.2, 0.9, -0.7).asDiagonal();  // inverted
          if (kind == 2) d = Vector3d(1, 1, 0).asDiagonal();         // flat
          if (kind == 3) d = Matrix3d::Zero();                       // collapsed to a point
          const Vector3d shift = rng.vec(-1, 1);
          for (int c = 0; c < 8; ++c) {
            const uint32_t i = uint32_t(8 * cl + (c * 5) % 8);  // scattered order
            indices[cl][c] = i;
            const Vector3d q = 0.1 * Vector3d(c & 1, (c >> 1) & 1, (c >> 2) & 1);
            for (int e = 0; e < 3; ++e) rest[3 * (8 * cl + c) + e] = q[e];
            set(x, i, r * d * q + shift + (kind == 3 ? Vector3d::Zero() : rng.vec(-0.01, 0.01)));
            inv_mass[i] = kind == 4 && c == 2 ? 0.0 : rng.uniform(0.5, 2.0);
          }
        }
        std::vector<Quaterniond> rotations(kClusters, Quaterniond::Identity());
        for (int cl = 0; cl < lanes; ++cl) {
          if ((trial + cl) % 6 == 5) rotations[cl].coeffs() *= 1.5;  // not unit
          if ((trial + cl) % 6 == 0) rotations[cl] = rng.rotation();
        }
        std::vector<double> x_scalar = x;
        std::vector<Quaterniond> rotations_scalar = rotations;
        ShapeBlock block;
        std::array<ShapeRest, kClusters> frames;
        for (int cl = 0; cl < lanes; ++cl) {
          REQUIRE(shape_matching_rest(inv_mass.data(), indices[cl].data(), &rest[24 * cl], 8, frames[cl]));
          shape_block_add(block, uint32_t(cl), indices[cl].data(), frames[cl]);
        }
        CHECK(block.lanes == lanes);
        for (int solve = 0; solve < 4; ++solve) {
          const double stiffness = solve % 2 ? 1.0 : 0.6;
          solve_shape_blocks(isa, x.data(), &block, 0, 1, stiffness, rotations.data(), trial % 2 == 0);
          for (int cl = 0; cl < lanes; ++cl)
            solve_shape_matching(x_scalar.data(), indices[cl].data(), frames[cl], stiffness, rotations_scalar[cl], 0);
          for (size_t k = 0; k < x.size(); ++k) REQUIRE(x[k] == x_scalar[k]);
          for (int cl = 0; cl < lanes; ++cl) {
            CHECK(rotations[cl].coeffs() == rotations_scalar[cl].coeffs());
            // A rotation: finite, unit, so its matrix is orthonormal with determinant 1.
            REQUIRE(finite_unit(rotations[cl]));
            const Matrix3d m = rotations[cl].toRotationMatrix();
            CHECK((m.transpose() * m - Matrix3d::Identity()).cwiseAbs().maxCoeff() < 1e-12);
            CHECK(std::fabs(m.determinant() - 1.0) < 1e-12);
          }
          // Lanes beyond `lanes` were never written: their particles are still zero.
          for (size_t k = 24 * size_t(lanes); k < x.size(); ++k) CHECK(x[k] == 0.0);
        }
      }
    }
  }

  // A range of blocks against the scalar path cluster by cluster in order, on every kernel path:
  // three blocks of one colour (no shared particle; the last with 1 to 8 clusters) with anchored
  // particles, then one-cluster blocks that share particles (the overflow colour's), whose solves
  // must follow one another. The colour's blocks are solved as disjoint (two at once on the AVX-512
  // path, an odd one alone) and, every other solve, with the rest in one call as not disjoint.
  TEST_CASE("solve_shape_blocks over a range equals the scalar solves in order, also with shared particles") {
    for (const KernelIsa isa : kernel_paths()) {
      CAPTURE(int(isa));
      Rng rng(49);
      for (int trial = 0; trial < 40; ++trial) {
        const int kFull = 3, kShared = 3;
        const int colour = kShapeLanes * kFull - trial % kShapeLanes;  // clusters in the colour's blocks
        const int clusters = colour + kShared;
        std::vector<double> x(3 * 8 * clusters), rest(3 * 8 * clusters), inv_mass(8 * clusters);
        std::vector<std::array<uint32_t, 8>> indices(clusters);
        for (int cl = 0; cl < clusters; ++cl) {
          const Matrix3d r = rng.rotation().toRotationMatrix() * random_stretch(rng, 0.8, 1.2);
          const Vector3d shift = rng.vec(-1, 1);
          for (int c = 0; c < 8; ++c) {
            // The shared clusters take their first four particles from the previous cluster.
            const bool shared = cl > colour && c < 4;
            const uint32_t i = shared ? indices[cl - 1][c + 4] : uint32_t(8 * cl + (c * 3) % 8);
            indices[cl][c] = i;
            const Vector3d q = 0.1 * Vector3d(c & 1, (c >> 1) & 1, (c >> 2) & 1);
            for (int e = 0; e < 3; ++e) rest[3 * (8 * cl + c) + e] = q[e];
            if (shared) continue;
            set(x, i, r * q + shift + rng.vec(-0.01, 0.01));
            inv_mass[i] = (trial + cl + c) % 11 == 0 ? 0.0 : rng.uniform(0.5, 2.0);
          }
        }
        std::vector<ShapeBlock> blocks(kFull + kShared);
        std::vector<ShapeRest> frames(clusters);
        for (int cl = 0; cl < clusters; ++cl) {
          REQUIRE(shape_matching_rest(inv_mass.data(), indices[cl].data(), &rest[24 * cl], 8, frames[cl]));
          shape_block_add(blocks[cl < colour ? cl / kShapeLanes : kFull + cl - colour], uint32_t(cl),
                          indices[cl].data(), frames[cl]);
        }
        std::vector<Quaterniond> rotations(clusters, Quaterniond::Identity());
        std::vector<double> x_scalar = x;
        std::vector<Quaterniond> rotations_scalar = rotations;
        for (int solve = 0; solve < 4; ++solve) {
          if (solve % 2 == 0) {
            solve_shape_blocks(isa, x.data(), blocks.data(), 0, kFull, 0.8, rotations.data(), true);
            solve_shape_blocks(isa, x.data(), blocks.data(), kFull, kFull + kShared, 0.8, rotations.data(), false);
          } else {
            solve_shape_blocks(isa, x.data(), blocks.data(), 0, uint32_t(blocks.size()), 0.8, rotations.data(), false);
          }
          for (int cl = 0; cl < clusters; ++cl)
            solve_shape_matching(x_scalar.data(), indices[cl].data(), frames[cl], 0.8, rotations_scalar[cl], 0);
          for (size_t k = 0; k < x.size(); ++k) REQUIRE(x[k] == x_scalar[k]);
          for (int cl = 0; cl < clusters; ++cl) CHECK(rotations[cl].coeffs() == rotations_scalar[cl].coeffs());
        }
      }
    }
  }

  // The rotation step against the full extract_rotation where both apply: warm-started near the
  // answer, repeated steps land on the polar rotation (the step's half angle without trigonometry
  // takes the same step as atan, cos and sin).
  TEST_CASE("extract_rotation_step: repeated from a nearby warm start reaches the polar rotation") {
    Rng rng(48);
    for (int trial = 0; trial < 200; ++trial) {
      const Quaterniond r = rng.rotation();
      const Matrix3d a = r.toRotationMatrix() * random_stretch(rng, 0.5, 2.0);
      const Vector3d axis = rng.unit();
      Quaterniond q = Quaterniond(Eigen::AngleAxisd(rng.uniform(0.0, 0.5), axis)) * r;
      for (int step = 0; step < 6; ++step) q = extract_rotation_step(a, q, kShapeRotationIterations);
      CHECK(finite_unit(q));
      CHECK(rotation_distance(q, r) < 1e-9);
    }
  }

  // The solver's inlined stretch (alpha~ hoisted) against the XPBD formula written out.
  TEST_CASE("solve_distance_alpha equals the XPBD distance update written out") {
    Rng rng(43);
    for (int trial = 0; trial < 500; ++trial) {
      std::vector<double> x = {rng.uniform(-1, 1), rng.uniform(-1, 1), rng.uniform(-1, 1),
                               rng.uniform(-1, 1), rng.uniform(-1, 1), rng.uniform(-1, 1)};
      const std::vector<double> w = {trial % 5 == 0 ? 0.0 : rng.uniform(0.1, 2.0), rng.uniform(0.1, 2.0)};
      const double rest = rng.uniform(0.1, 2.0), alpha = trial % 2 ? 0.0 : rng.uniform(0.0, 1.0);
      double lambda = rng.uniform(-0.1, 0.1);
      const Vector3d d = get(x, 0) - get(x, 1);
      const double dl = (-(d.norm() - rest) - alpha * lambda) / (w[0] + w[1] + alpha);
      const Vector3d xi = get(x, 0) + w[0] * dl * d.normalized(), xj = get(x, 1) - w[1] * dl * d.normalized();
      const double lambda_expected = lambda + dl;
      solve_distance_alpha(x.data(), w.data(), 0, 1, rest, alpha, lambda);
      CHECK((get(x, 0) - xi).norm() < 1e-14);
      CHECK((get(x, 1) - xj).norm() < 1e-14);
      CHECK(std::fabs(lambda - lambda_expected) < 1e-14);
    }
  }

  // The rows eight or four at a time (a colour group: no shared particle) on every kernel path
  // against the rows one by one: the same bits, with the cases that return early (coincident
  // particles, both anchored, a NaN position) among them, row counts that are not multiples of
  // eight or four and ranges that start inside.
  TEST_CASE("solve_stretch_rows: disjoint rows eight or four at a time give the bits of the rows one by one") {
    for (const KernelIsa isa : kernel_paths()) {
      CAPTURE(int(isa));
      Rng rng(59);
      for (int trial = 0; trial < 200; ++trial) {
        const uint32_t rows_count = uint32_t(1 + trial % 37);
        std::vector<double> x(6 * rows_count), inv_mass(2 * rows_count);
        std::vector<StretchRow> rows;
        const std::vector<uint32_t> order = rng.order(2 * rows_count);
        for (size_t k = 0; k < x.size(); ++k) x[k] = rng.uniform(-1, 1);
        for (uint32_t r = 0; r < rows_count; ++r) {
          const uint32_t a = order[2 * r], b = order[2 * r + 1];
          const int kind = int(r + trial) % 7;
          inv_mass[a] = kind == 1 || kind == 2 ? 0.0 : rng.uniform(0.1, 2.0);
          inv_mass[b] = kind == 2 ? 0.0 : rng.uniform(0.1, 2.0);
          if (kind == 3) set(x, b, get(x, a));                                     // coincident
          if (kind == 4) x[3 * a + 1] = std::numeric_limits<double>::quiet_NaN();  // not finite
          rows.push_back(stretch_row(inv_mass.data(), a, b, rng.uniform(0.1, 2.0)));
        }
        std::vector<double> lambda(rows_count);
        for (double& l : lambda) l = rng.uniform(-0.1, 0.1);
        const double alpha = trial % 3 == 0 ? 0.0 : rng.uniform(0.0, 1.0);
        const uint32_t begin = uint32_t(trial % 3) % rows_count;
        std::vector<double> x_one = x, lambda_one = lambda;
        for (int sweep = 0; sweep < 3; ++sweep) {
          solve_stretch_rows(isa, x.data(), rows.data(), lambda.data(), begin, rows_count, alpha, true);
          solve_stretch_rows(x_one.data(), rows.data(), lambda_one.data(), begin, rows_count, alpha, false);
        }
        for (size_t k = 0; k < x.size(); ++k) {
          if (std::isnan(x_one[k])) {
            CHECK(std::isnan(x[k]));
          } else {
            REQUIRE(x[k] == x_one[k]);
          }
        }
        for (uint32_t r = 0; r < rows_count; ++r) REQUIRE(lambda[r] == lambda_one[r]);
      }
    }
  }

  TEST_CASE("solve_elastic_blocks: a colour's hexahedra eight or four at a time give the bits of the rows one by one") {
    for (const KernelIsa isa : kernel_paths()) {
      CAPTURE(int(isa));
      Rng rng(61);
      for (int trial = 0; trial < 120; ++trial) {
        const uint32_t rows_count = uint32_t(1 + trial % 19);
        const double side = rng.uniform(0.005, 0.05);
        std::vector<double> x(24 * rows_count), previous, inv_mass(8 * rows_count);
        const std::vector<uint32_t> order = rng.order(8 * rows_count);
        std::vector<ElasticRow> rows(rows_count);
        // Identity in the slots no row uses (Eigen leaves a default quaternion uninitialised: a NaN
        // there compared unequal to its own copy, depending on what the heap held before).
        std::vector<Quaterniond> rotation(rows_count + 3, Quaterniond::Identity());
        for (uint32_t r = 0; r < rows_count; ++r) {
          ElasticRow& row = rows[r];
          row.piece = rows_count + 2 - r;  // one slot per piece, not the row's index
          const int kind = int(r + trial) % 8;
          const Vector3d origin = rng.vec(-1, 1);
          const Quaterniond turn = rng.rotation();
          for (int c = 0; c < 8; ++c) {
            const uint32_t p = order[8 * r + c];
            row.p[c] = p;
            Vector3d corner = side * Vector3d(c & 1, (c >> 1) & 1, (c >> 2) & 1);
            if (kind == 3) corner.z() = 0.0;                  // flattened
            if (kind == 4) corner.x() = -corner.x();          // inverted
            if (kind == 6 && c == 7) corner = Vector3d::Zero();  // two corners on one point
            set(x, p, origin + turn * corner + 0.2 * side * rng.vec(-1, 1));
            inv_mass[p] = kind == 5 && c < 4 ? 0.0 : rng.uniform(0.5, 4.0);  // kind 5: anchored face
            row.w[c] = inv_mass[p];
            row.octant[c] = kind == 1 && c % 3 == 0 ? 0.0 : rng.uniform(0.1, 1.0) * side * side * side / 16.0;
          }
          row.volume = kind == 2 ? 0.0 : side * side * side * rng.uniform(0.2, 1.0);  // kind 2: no material
          // Warm starts: near the turn, or not unit (kind 7: extract_rotation_step's fallback).
          Quaterniond q = kind == 7 ? Quaterniond(2.0, 0.1, 0.0, 0.0) : rng.rotation();
          rotation[row.piece] = q;
        }
        previous = x;
        for (double& v : x) v += rng.uniform(-0.01, 0.01) * side;
        std::vector<double> lambda(size_t(kElasticConstraints) * rows_count);
        for (double& l : lambda) l = rng.uniform(-1e-3, 1e-3);
        const double h = 1.0 / 60.0 / double(1 + trial % 5);
        const ElasticConstants k = elastic_constants(rng.uniform(1e3, 1e7), trial % 6 == 0 ? 0.0 : rng.uniform(0.1, 0.499),
                                                     trial % 2 ? 0.01 : 0.0, side, h);
        const uint32_t begin = uint32_t(trial % 3) % rows_count;
        std::vector<double> x_one = x, lambda_one = lambda;
        std::vector<Quaterniond> rotation_one = rotation;
        // Every other trial with the incompatible modes' amplitudes (the global step's).
        std::vector<double> enhancement(9 * rotation.size());
        for (double& b : enhancement) b = rng.uniform(-0.05, 0.05);
        const double* modes = (trial / 2) % 2 ? enhancement.data() : nullptr;
        for (int sweep = 0; sweep < 3; ++sweep) {
          solve_elastic_blocks(isa, x.data(), previous.data(), rows.data(), lambda.data(), begin, rows_count, k,
                               rotation.data(), modes, true);
          solve_elastic_rows(x_one.data(), previous.data(), rows.data(), lambda_one.data(), begin, rows_count, k,
                             rotation_one.data(), modes);
        }
        CAPTURE(trial);
        for (size_t i = 0; i < x.size(); ++i) {
          CAPTURE(i);
          REQUIRE(x[i] == x_one[i]);
        }
        for (size_t i = 0; i < lambda.size(); ++i) REQUIRE(lambda[i] == lambda_one[i]);
        for (size_t i = 0; i < rotation.size(); ++i) REQUIRE(rotation[i].coeffs() == rotation_one[i].coeffs());
      }
    }
  }
}
