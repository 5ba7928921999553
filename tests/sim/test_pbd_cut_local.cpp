// The PBD model update after a cut relabels only blocks whose material components a cut can split,
// and a slit still joined around its front leaves the pieces untouched (sim/pbd_labels.cpp keeps_components).
#include "fixtures.h"

#include "sim/pbd.h"
#include "sim/pbd_internal.h"
#include "sim/shapes.h"

#include <doctest/doctest.h>

using namespace dvx;

TEST_SUITE("pbd") {
  TEST_CASE("a slit joined around its front keeps its blocks' pieces, crossing a block splits them, as a fresh build does") {
    const TriMesh box = make_box(Vec3d(0.0013, 0.0021, 0.0007), Vec3d(1.0, 0.5, 0.5), Eigen::Matrix3d::Identity(), 1);
    // Two blades: level (it cuts y edges only: spans stay whole) and slanted in x and z (it cuts x
    // edges too: spans split), each across the whole box in steps of about one fine voxel.
    const struct {
      BladePose from, to;
    } cuts[] = {{{Vec3d(-1.2, 0.101, -1), Vec3d(-1.2, 0.101, 1)}, {Vec3d(1.2, 0.101, -1), Vec3d(1.2, 0.101, 1)}},
                {{Vec3d(-1.2, -0.5, -1), Vec3d(-1.2, -0.1, 1)}, {Vec3d(1.2, 0.1, -1), Vec3d(1.2, 0.5, 1)}}};
    for (int sim_resolution : {4, 8}) {
      CAPTURE(sim_resolution);
      dvx_test::PbdScene s;
      dvx_test::make_pbd_scene(s, box, 64, sim_resolution, PbdParams{});
      const uint32_t pieces_before = live_pieces(s.pbd.model);
      PbdCutStats total, level;
      for (const auto& c : cuts) {
        dvx_test::sweep_steps(s.model, s.cut, c.from, c.to, 80, [&](int) {
          PbdCutStats step;
          pbd_apply_cut(s.model, s.cut, s.pbd.model, s.pbd.data, &step);
          const auto add = [](PbdCutStats& t, const PbdCutStats& d) {
            t.sim_voxels += d.sim_voxels;
            t.kept_by_search += d.kept_by_search;
            t.span_relabels += d.span_relabels;
            t.components_changed += d.components_changed;
          };
          add(total, step);
          if (&c == cuts) add(level, step);
          std::string error;
          REQUIRE_MESSAGE(check_pbd_state(s.model, s.cut, s.pbd.model, s.pbd.data, error), error);
        });
      }
      MESSAGE("blocks looked at: " << total.sim_voxels << " (level blade " << level.sim_voxels
                                   << "), kept by the search: " << total.kept_by_search << " (" << level.kept_by_search
                                   << "), relabelled by spans: " << total.span_relabels << " (" << level.span_relabels
                                   << "), with changed components: " << total.components_changed << " ("
                                   << level.components_changed << ")");
      // The level blade's slit is found joined around its front in most blocks; the blocks each blade
      // crosses split. (The slanted sheet separates the spans of neighbouring rows: those blocks are
      // relabelled, and mostly found unchanged by the relabel.)
      CHECK(level.kept_by_search * 2 > level.sim_voxels);
      CHECK(level.components_changed > 0);
      CHECK(total.components_changed > level.components_changed);
      CHECK(total.kept_by_search + total.span_relabels == total.sim_voxels);
      CHECK(live_pieces(s.pbd.model) > pieces_before);
      // The same pieces and particles as a model built from scratch on the cut state.
      PbdState fresh;
      std::string error;
      PbdParams params;
      params.resolution = 64;
      params.sim_resolution = sim_resolution;
      REQUIRE(init_pbd(s.model, s.cut, params, fresh.model, fresh.data, error));
      CHECK(live_pieces(fresh.model) == live_pieces(s.pbd.model));
      CHECK(live_particles(fresh.model) == live_particles(s.pbd.model));
      CHECK(total_mass(fresh.model) == total_mass(s.pbd.model));
      // The spans label every block as label_block does (init labels by spans), node for node and in
      // the same order, whether the block's cut record was kept up to date through the cuts or made
      // at init from the cut state.
      uint32_t blocks = 0, cut_blocks = 0, differ = 0;
      for (const PbdModel* m : {&s.pbd.model, &fresh.model}) {
        const uint32_t nodes = pbd_internal::block_nodes(*m);
        std::vector<uint8_t> by_voxels(nodes), by_spans(nodes);
        std::vector<uint32_t> parent;
        SpanScratch spans;
        for (uint32_t sv = 0; sv < uint32_t(m->sx * m->sy * m->sz); ++sv) {
          const uint8_t a = pbd_internal::label_block(s.model, s.cut, *m, sv, parent, by_voxels.data());
          const uint8_t b = pbd_internal::label_block_spans(s.model, s.cut, *m, sv, spans, by_spans.data());
          ++blocks;
          cut_blocks += a > 1;
          differ += a != b || by_voxels != by_spans;
        }
      }
      CHECK(cut_blocks > 10);
      CHECK(differ == 0);
      MESSAGE(blocks << " blocks labelled both ways, " << cut_blocks << " with several pieces");
    }
  }
}
