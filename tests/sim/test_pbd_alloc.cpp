// The PBD model update of a cut step allocates nothing in steady state: its scratch is kept in the
// model, and what grows (slots, labels, colour groups) grows geometrically. Counted with a global
// operator new of this test binary (enabled only around the calls measured).
#include "sim/cut.h"
#include "sim/pbd.h"
#include "sim/shapes.h"

#include "fixtures.h"

#include <doctest/doctest.h>

#include <cstdlib>
#include <new>

// ThreadSanitizer's runtime defines the global operator new and delete itself (a second definition
// fails to link); its build (tools/sanitize.sh thread) runs the engine tests only, so this binary
// there counts nothing and the test says so.
#if defined(__SANITIZE_THREAD__)
#define DVX_TSAN 1
#elif defined(__has_feature)
#if __has_feature(thread_sanitizer)
#define DVX_TSAN 1
#endif
#endif

namespace {

bool g_counting = false;
uint64_t g_allocations = 0;

}  // namespace

#ifndef DVX_TSAN
void* operator new(std::size_t size) {
  if (g_counting) ++g_allocations;
  if (void* p = std::malloc(size ? size : 1)) return p;
  throw std::bad_alloc();
}
void* operator new[](std::size_t size) { return operator new(size); }
void operator delete(void* p) noexcept { std::free(p); }
void operator delete[](void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }
void operator delete[](void* p, std::size_t) noexcept { std::free(p); }
// The nothrow forms too (std::stable_sort's temporary buffer uses them): every unaligned new and
// delete of the binary then meets in malloc / free (AddressSanitizer checks that they match).
void* operator new(std::size_t size, const std::nothrow_t&) noexcept {
  if (g_counting) ++g_allocations;
  return std::malloc(size ? size : 1);
}
void* operator new[](std::size_t size, const std::nothrow_t& tag) noexcept { return operator new(size, tag); }
void operator delete(void* p, const std::nothrow_t&) noexcept { std::free(p); }
void operator delete[](void* p, const std::nothrow_t&) noexcept { std::free(p); }
#endif

using namespace dvx;

TEST_SUITE("pbd") {
  TEST_CASE("a long progressive cut: the PBD update allocates only when a container grows, never per step") {
#ifdef DVX_TSAN
    MESSAGE("skipped under ThreadSanitizer: its runtime owns operator new");
    return;
#endif
    // A block 1 x 2 x 1 at 64 with 8 simulation voxels along y (8^3 fine voxels each), cut along four
    // slanted planes in 45 steps each (about a fine voxel per step): every step in the material gives
    // fine voxels new cut edges and relabels the blocks holding them.
    const TriMesh box = make_box(Vec3d(0.0013, 0.0021, 0.0007), Vec3d(0.5, 1.0, 0.5), Eigen::Matrix3d::Identity(), 1);
    dvx_test::PbdScene s;
    dvx_test::make_pbd_scene(s, box, 64, 8, PbdParams{});
    const int steps = 45;
    uint64_t total = 0;
    int allocating = 0, cutting = 0;
    for (int i = 1; i <= 4 * steps; ++i) {
      const double height = -0.6 + 0.35 * ((i - 1) / steps);
      const double x0 = -0.7 + 1.4 * ((i - 1) % steps) / steps, x = x0 + 1.4 / steps;
      const BladePose previous{Vec3d(x0, height + 0.3 * x0, -2), Vec3d(x0, height + 0.3 * x0, 2)};
      const BladePose next{Vec3d(x, height + 0.3 * x, -2), Vec3d(x, height + 0.3 * x, 2)};
      cut_step(s.model, s.cut, previous, next);
      PbdCutStats stats;
      g_allocations = 0;
      g_counting = true;
      pbd_apply_cut(s.model, s.cut, s.pbd.model, s.pbd.data, &stats);
      g_counting = false;
      if (stats.sim_voxels == 0) continue;
      ++cutting;
      total += g_allocations;
      allocating += g_allocations > 0;
    }
    std::string error;
    REQUIRE_MESSAGE(check_pbd_state(s.model, s.cut, s.pbd.model, s.pbd.data, error), error);
    MESSAGE("steps relabelling: " << cutting << ", with an allocation: " << allocating << ", allocations: " << total);
    REQUIRE(cutting > 100);
    // Growth only: a per-step allocation would show in every step.
    CHECK(allocating * 5 < cutting);
    CHECK(total < uint64_t(cutting) * 2);
  }

  TEST_CASE("through-cuts that double the surface move none of its arrays, nor the embedding's") {
    // A block 1 x 2 x 1 at 32 sliced through by horizontal planes, a fine voxel's travel a step, until
    // its surface vertices have doubled: the surface keeps 4 times its first vertex and quad slots
    // (sim/cut.cpp), the embedding follows the surface's capacity, so no cut step copies them (the
    // step that outgrew them at 1.5 times cost 30 ms at 256).
    const TriMesh box = make_box(Vec3d(0.0013, 0.0021, 0.0007), Vec3d(0.5, 1.0, 0.5), Eigen::Matrix3d::Identity(), 1);
    dvx_test::PbdScene s;
    dvx_test::make_pbd_scene(s, box, 32, 8, PbdParams{});
    const CutSurface& f = s.cut.surface;
    const size_t first = f.positions.size();
    const void* arrays[] = {f.positions.data(), f.vertex_piece.data(), f.vertex_patch.data(), f.vertex_half_edges.data(),
                            f.triangles.data(), f.quad_half_edge.data(), f.triangle_cut.data(), s.pbd.model.embedding.data(),
                            s.pbd.data.deformed.data()};
    int cuts = 0;
    for (double y = -0.8; y < 0.85 && f.positions.size() < 2 * first; y += 0.2, ++cuts) {
      for (int i = 1; i <= 48; ++i) {
        const double x0 = -0.8 + 1.6 * (i - 1) / 48, x = -0.8 + 1.6 * i / 48;
        cut_step(s.model, s.cut, {Vec3d(x0, y, -2), Vec3d(x0, y, 2)}, {Vec3d(x, y, -2), Vec3d(x, y, 2)});
        pbd_apply_cut(s.model, s.cut, s.pbd.model, s.pbd.data);
        pbd_step(s.cut, s.pbd.model, s.pbd.data);
      }
    }
    MESSAGE("surface vertex slots " << first << " -> " << f.positions.size() << " after " << cuts << " through-cuts");
    REQUIRE(f.positions.size() >= 2 * first);
    const void* now[] = {f.positions.data(), f.vertex_piece.data(), f.vertex_patch.data(), f.vertex_half_edges.data(),
                         f.triangles.data(), f.quad_half_edge.data(), f.triangle_cut.data(), s.pbd.model.embedding.data(),
                         s.pbd.data.deformed.data()};
    for (size_t k = 0; k < std::size(arrays); ++k) CHECK_MESSAGE(arrays[k] == now[k], "array " << k << " moved");
    std::string error;
    CHECK_MESSAGE(check_pbd_state(s.model, s.cut, s.pbd.model, s.pbd.data, error), error);
  }

  TEST_CASE("a cut step that changes no voxel leaves the PBD model alone without allocating") {
#ifdef DVX_TSAN
    MESSAGE("skipped under ThreadSanitizer: its runtime owns operator new");
    return;
#endif
    const TriMesh box = make_box(Vec3d(0.0013, 0.0021, 0.0007), Vec3d(0.5, 1.0, 0.5), Eigen::Matrix3d::Identity(), 1);
    dvx_test::PbdScene s;
    dvx_test::make_pbd_scene(s, box, 32, 8, PbdParams{});
    // Far outside the object: the blade crosses no material.
    cut_step(s.model, s.cut, {Vec3d(5, 5, -1), Vec3d(5, 5, 1)}, {Vec3d(6, 5, -1), Vec3d(6, 5, 1)});
    g_allocations = 0;
    g_counting = true;
    const uint32_t relabelled = pbd_apply_cut(s.model, s.cut, s.pbd.model, s.pbd.data);
    g_counting = false;
    CHECK(relabelled == 0);
    CHECK(g_allocations == 0);
  }
}
