#include "sim/contact.h"

#include <algorithm>
#include <cmath>
#include <limits>
#ifdef __SSE2__
#include <emmintrin.h>
#endif

namespace dvx {
ContactPoint plane_contact(const ContactPlane& plane, const uint32_t particles[8], const double weights[8]) {
  ContactPoint c;
  std::copy(particles, particles + 8, c.particles);
  std::copy(weights, weights + 8, c.weights);
  c.count = 8;
  c.normal = plane.normal;
  c.target = plane.normal.dot(plane.point);
  c.static_friction = plane.static_friction;
  c.kinetic_friction = plane.kinetic_friction;
  return c;
}

void contacts_clear(ContactSet& set) {
  set.points.clear();
  set.group_begin.clear();
  set.batch_begin.clear();
  set.staged.clear();
  set.staged_key.clear();
}

void contacts_add(ContactSet& set, uint32_t batch, uint32_t group, const ContactPoint& point) {
  set.staged.push_back(point);
  set.staged_key.push_back((uint64_t(batch) << 32) | group);
}

void contacts_finish(ContactSet& set) {
  // Sort by (batch, group), stable: a group's points keep the order they were added in. The gathers
  // add each batch's groups in ascending order: then a counting sort by batch is that sort, in O(n).
  const uint32_t n = uint32_t(set.staged.size());
  set.order.resize(n);
  constexpr uint32_t kBatches = 64;
  uint32_t start[kBatches + 1] = {}, last[kBatches] = {};
  bool ascending = true;
  for (uint32_t i = 0; i < n && ascending; ++i) {
    const uint64_t batch = set.staged_key[i] >> 32;
    const uint32_t group = uint32_t(set.staged_key[i]);
    ascending = batch < kBatches && (start[batch + 1] == 0 || group >= last[batch]);
    if (!ascending) break;
    last[batch] = group;
    ++start[batch + 1];
  }
  if (ascending) {
    for (uint32_t b = 0; b < kBatches; ++b) start[b + 1] += start[b];
    for (uint32_t i = 0; i < n; ++i) set.order[start[set.staged_key[i] >> 32]++] = i;
  } else {
    for (uint32_t i = 0; i < n; ++i) set.order[i] = i;
    std::stable_sort(set.order.begin(), set.order.end(),
                     [&](uint32_t a, uint32_t b) { return set.staged_key[a] < set.staged_key[b]; });
  }
  set.points.resize(n);
  set.group_begin.clear();
  set.batch_begin.assign(1, 0);
  for (uint32_t i = 0; i < n; ++i) {
    const uint64_t key = set.staged_key[set.order[i]];
    const bool new_group = i == 0 || key != set.staged_key[set.order[i - 1]];
    if (new_group) {
      // Close the batches before this one (empty batches have no groups).
      while (set.batch_begin.size() <= size_t(key >> 32)) set.batch_begin.push_back(uint32_t(set.group_begin.size()));
      set.group_begin.push_back(i);
    }
    set.points[i] = set.staged[set.order[i]];
  }
  set.group_begin.push_back(n);
  set.batch_begin.push_back(uint32_t(set.group_begin.size() - 1));
}

void contacts_begin_substep(ContactSet& set) {
  for (ContactPoint& c : set.points) {
    c.normal_total = 0.0;
    c.friction_total = Vec3d::Zero();
    c.solves = 0;
  }
}

namespace {

// sum_k w_k p_k (p_k: 3 doubles at x + 3 particles[k]; a prepared point has no zero weight, see
// prepare_contact), each coordinate summed in the order of k -- the same sums as Vec3d's r += w_k
// p_k -- with x and y in one SSE2 register and no temporary vectors. This is most of a contact's
// solve (most points are not pressed and change nothing).
Vec3d weighted_point(const double* x, const uint32_t* particles, const double* weights, uint32_t count) {
#ifdef __SSE2__
  __m128d xy = _mm_setzero_pd();
  double z = 0.0;
  for (uint32_t k = 0; k < count; ++k) {
    const double w = weights[k];
    const double* p = x + 3 * size_t(particles[k]);
    xy = _mm_add_pd(xy, _mm_mul_pd(_mm_set1_pd(w), _mm_loadu_pd(p)));
    z += w * p[2];
  }
  alignas(16) double out[2];
  _mm_store_pd(out, xy);
  return Vec3d(out[0], out[1], z);
#else
  Vec3d r = Vec3d::Zero();
  for (uint32_t k = 0; k < count; ++k) {
    const double* p = x + 3 * size_t(particles[k]);
    r += weights[k] * Vec3d(p[0], p[1], p[2]);
  }
  return r;
#endif
}

// The lever cap (sim/contact.h, kMaxLever), once per step. W = sum_k w_k^2 / m_k,
// W_eff = max(W, max_k |w_k| / m_k / kMaxLever): a requested correction d moves particle k by
// (w_k / m_k / W_eff) d and the point by gain d (gain = W / W_eff: 1 unless the point is nearly
// anchored, when it barely moves).
void prepare_contact(const double* inv_mass, ContactPoint& c) {
  if (!c.prepared) {
    // Zero weights dropped (in order): their terms add nothing to the sums below nor to the point's
    // sums (a sum that starts at +0 is never -0, so adding a zero product leaves it as it was), and
    // their particles are not moved; a point on a piece's face or edge has 4 or 6 of them.
    uint32_t kept = 0;
    for (uint32_t k = 0; k < c.count; ++k) {
      if (c.weights[k] == 0.0) continue;
      c.particles[kept] = c.particles[k];
      c.weights[kept] = c.weights[k];
      ++kept;
    }
    c.count = kept;
    double w = 0.0, lever = 0.0;
    for (uint32_t k = 0; k < c.count; ++k) {
      const double a = c.weights[k], m = inv_mass[c.particles[k]];
      w += a * a * m;
      lever = std::max(lever, std::abs(a) * m);
    }
    const bool capped = lever > kMaxLever * w;
    const double inv_w = !(w > 0.0) ? 0.0 : capped ? kMaxLever / lever : 1.0 / w;
    c.gain = !(w > 0.0) ? 0.0 : capped ? w * inv_w : 1.0;
    for (uint32_t k = 0; k < c.count; ++k) c.scale[k] = c.weights[k] * inv_mass[c.particles[k]] * inv_w;
    c.prepared = true;
  }
  c.started = false;
}

}  // namespace

void solve_contact_point(double* x, const double* previous, const double* inv_mass, ContactPoint& c) {
  if (c.solves++ == 0) prepare_contact(inv_mass, c);
  if (!(c.gain > 0.0)) return;  // W = 0: nothing can move it
  // The relative point.
  const Vec3d r = weighted_point(x, c.particles, c.weights, c.count);
  const double gain = c.gain;
  const Vec3d& n = c.normal;

  // Normal: C = n . r - target >= 0, rigid (alpha = 0): dlambda = -C / W moves r by -C n. The total
  // over the substep stays >= 0 (projected Gauss-Seidel with accumulated clamping): a point pushed out
  // too far by an earlier iteration is pulled back by up to what it was pushed, never further. The
  // totals count what the point actually moved (gain x requested).
  const double request = std::max(c.target - n.dot(r), -c.normal_total / gain);
  Vec3d delta = request * n;  // the correction requested of the point
  c.normal_total += gain * request;
  if (c.normal_total > 0.0) {
    // The point's motion since the start of the substep (the start taken on the first need: most
    // points are never pressed, and `previous` does not change within a substep).
    if (!c.started) {
      c.start = weighted_point(previous, c.particles, c.weights, c.count);
      c.started = true;
    }
    Vec3d moved = r - c.start;
    moved += (gain * request) * n;
    // Friction: the total correction that would stop the tangential motion, clamped by Coulomb's cone.
    const Vec3d slide = moved - n.dot(moved) * n;
    Vec3d total = c.friction_total - slide;
    const double length = total.norm();
    if (length > c.static_friction * c.normal_total) {
      total *= length > 0.0 ? c.kinetic_friction * c.normal_total / length : 0.0;  // sliding
    }
    delta += total - c.friction_total;
    c.friction_total = gain == 1.0 ? total : c.friction_total + gain * (total - c.friction_total);
  }
  // Both corrections in one pass: x_k += scale_k delta.
  if (delta.x() == 0.0 && delta.y() == 0.0 && delta.z() == 0.0) return;
  for (uint32_t k = 0; k < c.count; ++k) {
    const double s = c.scale[k];
    if (s == 0.0) continue;
    double* p = x + 3 * size_t(c.particles[k]);
    p[0] += s * delta.x();
    p[1] += s * delta.y();
    p[2] += s * delta.z();
  }
}

void solve_contact_group(double* x, const double* previous, const double* inv_mass, ContactSet& set, uint32_t group) {
  for (uint32_t i = set.group_begin[group]; i < set.group_begin[group + 1]; ++i) {
    solve_contact_point(x, previous, inv_mass, set.points[i]);
  }
}

void project_particles_to_planes(double* x, const double* inv_mass, uint32_t begin, uint32_t end,
                                 const ContactPlane* planes, uint32_t plane_count, double depth) {
  for (uint32_t i = begin; i < end; ++i) {
    if (inv_mass[i] == 0.0) continue;
    double* p = x + 3 * size_t(i);
    double p0 = p[0], p1 = p[1], p2 = p[2];
    bool moved = false;
    for (uint32_t k = 0; k < plane_count; ++k) {
      const ContactPlane& plane = planes[k];
      const double n0 = plane.normal.x(), n1 = plane.normal.y(), n2 = plane.normal.z();
      // plane_distance written out, operation for operation as Eigen's 3-vector dot, (n0 e0 + n1 e1) +
      // n2 e2 (the same bits): through Vec3d the (x, y) packet went through the stack, and its 16-byte
      // load waited on the two 8-byte stores before it (a failed store forward per particle and plane).
      const double d = (n0 * (p0 - plane.point.x()) + n1 * (p1 - plane.point.y())) + n2 * (p2 - plane.point.z()) + depth;
      if (d >= 0.0) continue;
      p0 -= d * n0;
      p1 -= d * n1;
      p2 -= d * n2;
      moved = true;
    }
    if (!moved) continue;
    p[0] = p0;
    p[1] = p1;
    p[2] = p2;
  }
}

}  // namespace dvx
