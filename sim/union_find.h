// The one union-find labeller of small integer ids (a voxel's corners, its half-edge slots, the
// fine nodes of a simulation block), used by the cut surface (sim/cut*.cpp) and the PBD labelling
// (sim/pbd_labels.cpp, sim/pbd_internal.h CornerMembers). Plain arrays of parents, no allocation:
// path halving on find, and a union keeps the smaller root, so every root is the lowest id of its set
// and numbering the sets in id order is one pass (a root is met before its members).
#pragma once

#include <algorithm>

namespace dvx {

// Root of x (compresses the path by halving).
template <typename T>
T uf_find(T* parent, T x) {
  while (parent[x] != x) x = parent[x] = parent[parent[x]];
  return x;
}

// Joins the sets of x and y; returns the root of the union (the smaller of the two roots).
template <typename T>
T uf_unite(T* parent, T x, T y) {
  const T a = uf_find(parent, x), b = uf_find(parent, y);
  if (a != b) parent[std::max(a, b)] = std::min(a, b);
  return std::min(a, b);
}

}  // namespace dvx
