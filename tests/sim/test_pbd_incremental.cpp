// The caches derived from the PBD model follow the cuts incrementally (PbdModel::edits): the
// embedding's rows, the contact index and the shape-matching blocks updated from what each cut step
// changed equal the ones built from scratch, after every step of several cuts, and so do the
// positions they produce (bit for bit).
#include "sim/cut.h"
#include "sim/pbd.h"
#include "sim/shapes.h"
#include "sim/state_hash.h"

#include "fixtures.h"

#include <doctest/doctest.h>

#include <algorithm>
#include <cstring>
#include <map>
#include <tuple>
#include <vector>

using namespace dvx;

namespace {

using Scene = dvx_test::PbdScene;

// Two arrays of plain structs hold the same bytes (an empty array's data() may be null: memcmp's
// arguments must not be, even for no bytes).
template <class T>
bool same_bytes(const std::vector<T>& a, const std::vector<T>& b) {
  return a.size() == b.size() && (a.empty() || std::memcmp(a.data(), b.data(), a.size() * sizeof(T)) == 0);
}

uint64_t position_hash(const PbdState& s) {
  Fnv1a f;
  for (const Vec3d& p : s.data.position) f.bytes(p.data(), 3 * sizeof(double));
  return f.value;
}

// The embedding rows as a set (their order is free: each row writes its own slot).
std::vector<std::tuple<uint32_t, uint32_t, float, float, float>> row_set(const PbdState& s) {
  std::vector<std::tuple<uint32_t, uint32_t, float, float, float>> rows;
  for (const EmbedRow& r : s.data.cache.embed_rows) rows.emplace_back(r.slot, r.piece, r.u, r.v, r.w);
  std::sort(rows.begin(), rows.end());
  return rows;
}

// Each piece's shape-matching lane (its colour, and the bytes of what the lane holds), by piece: the
// blocks' order within a colour is free, what each cluster is solved with is not.
std::map<uint32_t, std::vector<uint8_t>> lanes_by_piece(const PbdState& s, uint32_t& overflow_order_hash) {
  std::map<uint32_t, std::vector<uint8_t>> lanes;
  Fnv1a overflow;
  for (int c = 0; c < kColourGroups; ++c) {
    for (const ShapeBlock& b : s.data.cache.shape_blocks[c]) {
      for (int l = 0; l < b.lanes; ++l) {
        std::vector<uint8_t> bytes;
        const auto put = [&](const void* p, size_t n) {
          const uint8_t* q = static_cast<const uint8_t*>(p);
          bytes.insert(bytes.end(), q, q + n);
        };
        put(&c, sizeof(c));
        put(&b.inv_total[l], sizeof(double));
        for (int k = 0; k < kShapeMaxParticles; ++k) {
          put(&b.index[k][l], sizeof(uint32_t));
          put(&b.mass[k][l], sizeof(double));
          put(&b.moves[k][l], 1);
          for (int e = 0; e < 3; ++e) put(&b.offset[k][e][l], sizeof(double));
        }
        CHECK(lanes.emplace(b.piece[l], bytes).second);  // a piece in one lane only
        if (c == kOverflowColour) overflow.add(b.piece[l]);
      }
    }
  }
  overflow_order_hash = uint32_t(overflow.value);
  return lanes;
}

// Everything a cache holds, compared between the incremental state `a` and the rebuilt one `b`.
void check_caches_equal(const PbdState& a, const PbdState& b) {
  CHECK(position_hash(a) == position_hash(b));
  CHECK(a.data.deformed == b.data.deformed);
  CHECK(row_set(a) == row_set(b));
  const ContactIndex& x = a.data.piece_contacts.index;
  const ContactIndex& y = b.data.piece_contacts.index;
  CHECK(x.slots == y.slots);
  CHECK(x.pieces == y.pieces);
  CHECK(x.slot_piece == y.slot_piece);
  CHECK(x.piece_begin == y.piece_begin);
  CHECK(x.piece_slots == y.piece_slots);
  if (x.bodies_updates == x.updates && y.bodies_updates == y.updates) {
    CHECK(x.mobile == y.mobile);
    CHECK(x.body_index == y.body_index);
    CHECK(x.bodies == y.bodies);
  }
  // The contact allowances (fresh slots found from the index's revisited ones, or by comparing all).
  const PieceContacts& pa = a.data.piece_contacts;
  const PieceContacts& pb = b.data.piece_contacts;
  REQUIRE(pa.seen.size() == pb.seen.size());
  CHECK(same_bytes(pa.seen, pb.seen));
  CHECK(pa.allowance == pb.allowance);
  uint32_t oa = 0, ob = 0;
  CHECK(lanes_by_piece(a, oa) == lanes_by_piece(b, ob));
  CHECK(oa == ob);  // the overflow colour in its group's order
  for (int c = 0; c < kColourGroups; ++c) {
    // As many blocks per colour (the solver's batches), and the same stretch rows in order.
    CHECK(a.data.cache.shape_blocks[c].size() == b.data.cache.shape_blocks[c].size());
    REQUIRE(a.data.cache.stretch_rows[c].size() == b.data.cache.stretch_rows[c].size());
    CHECK(same_bytes(a.data.cache.stretch_rows[c], b.data.cache.stretch_rows[c]));
  }
}

// A block cut by several blades: `s` keeps its caches, `fresh` forgets them before every step. One
// or two cut steps per solver step, steps that cut nothing, and (with `headless`) steps that do not
// embed in between.
void cut_and_compare(const PbdParams& params, bool headless) {
  Scene s;
  dvx_test::make_pbd_scene(s, make_box(Vec3d(0.003, 0.0, 0.002), Vec3d(0.5, 0.5, 0.5), Eigen::Matrix3d::Identity(), 1), 32, 8,
                           params);
  PbdState fresh = s.pbd;
  BladePose previous{Vec3d(-1, 0.013, -2), Vec3d(-1, 0.013, 2)};
  int steps = 0;
  uint64_t incremental = 0;
  const auto cut = [&](const BladePose& next) {
    cut_step(s.model, s.cut, previous, next);
    pbd_apply_cut(s.model, s.cut, s.pbd.model, s.pbd.data);
    pbd_apply_cut(s.model, s.cut, fresh.model, fresh.data);
    previous = next;
    std::string error;
    REQUIRE_MESSAGE(check_pbd_state(s.model, s.cut, s.pbd.model, s.pbd.data, error), error);
  };
  const auto step = [&]() {
    const uint64_t updates = s.pbd.data.piece_contacts.index.updates;
    pbd_step(s.cut, s.pbd.model, s.pbd.data, {}, !headless);
    pbd_forget_caches(fresh.data);
    pbd_step(s.cut, fresh.model, fresh.data, {}, !headless);
    // Headless: the surface embedded every third step only (after several cuts, when nothing but
    // the embedding reads the index).
    const bool embedded = !headless || steps % 3 == 0;
    if (headless && embedded) {
      pbd_embed(s.cut, s.pbd.model, s.pbd.data);
      pbd_embed(s.cut, fresh.model, fresh.data);
    }
    incremental += s.pbd.data.piece_contacts.index.updates != updates && !s.pbd.data.piece_contacts.index.rebuilt;
    if (embedded) {
      check_caches_equal(s.pbd, fresh);
    } else {
      CHECK(position_hash(s.pbd) == position_hash(fresh));
    }
    ++steps;
  };
  for (int i = 1; i <= 8; ++i) {  // through horizontally, one cut step per solver step
    const double x = -1.0 + 2.0 * i / 8;
    cut(BladePose{Vec3d(x, 0.013, -2), Vec3d(x, 0.013, 2)});
    step();
  }
  for (int i = 0; i < 5; ++i) step();  // no cut
  previous = BladePose{Vec3d(0.21, 1.0, -2), Vec3d(0.21, 1.0, 2)};
  for (int i = 1; i <= 12; i += 2) {  // vertically, two cut steps per solver step
    for (int k = i; k <= i + 1; ++k) {
      const double y = 1.0 - 2.0 * k / 12;
      cut(BladePose{Vec3d(0.21, y, -2), Vec3d(0.21, y, 2)});
    }
    step();
  }
  // A cut step that cuts nothing (the blade far away), then a slanted cut.
  previous = BladePose{Vec3d(5, 5, -1), Vec3d(5, 5, 1)};
  cut(BladePose{Vec3d(6, 5, -1), Vec3d(6, 5, 1)});
  step();
  previous = BladePose{Vec3d(-1, 0.4, -0.31), Vec3d(1, 0.2, -0.31)};
  for (int i = 1; i <= 6; ++i) {
    const double z = -0.31 + 0.6 * i / 6;
    cut(BladePose{Vec3d(-1, 0.4 - 0.2 * i / 6, z), Vec3d(1, 0.2 - 0.1 * i / 6, z)});
    step();
  }
  for (int i = 0; i < 5; ++i) step();
  CHECK(s.pbd.model.revision > 10);      // the cuts changed the model
  CHECK(incremental >= (headless ? 5u : 15u));  // and the index followed them without a rebuild
  MESSAGE("incremental index updates: " << incremental);
}

}  // namespace

TEST_SUITE("pbd") {
  TEST_CASE("the caches follow every cut step incrementally and equal a fresh build (contact on a tray)") {
    PbdParams params;
    ContactPlane tray;
    tray.point = Vec3d(0.0, -0.52, 0.0);
    params.planes.push_back(tray);
    cut_and_compare(params, false);
  }
  TEST_CASE("the caches follow every cut step incrementally and equal a fresh build (hanging, no contact, headless steps)") {
    PbdParams params;
    Aabb top;
    top.grow(Vec3d(-5, 0.4, -5));
    top.grow(Vec3d(5, 5, 5));
    params.fixed.push_back(top);
    params.piece_contact = false;
    cut_and_compare(params, true);
  }
}
