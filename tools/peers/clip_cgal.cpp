// divvox_peers clip: CGAL's remeshing cut. The bench-cut plane clips the mesh twice (lower and upper
// side, closed volumes: the two pieces of a cut), timed on fresh copies; the last repeat's output is
// measured (closedness, components) and its cut triangles classified for angle quality (Fig. 13).
#include "tools/peers/peers.h"

#include "bench/bench_json.h"
#include "engine/output.h"
#include "sim/surface_metrics.h"
#include "sim/triangle_quality.h"

#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/Polygon_mesh_processing/clip.h>
#include <CGAL/Polygon_mesh_processing/triangulate_faces.h>
#include <CGAL/Surface_mesh.h>
#include <CGAL/boost/graph/helpers.h>
#include <CGAL/version.h>

#include <nlohmann/json.hpp>

#include <cmath>
#include <cstdio>
#include <filesystem>

namespace dvx::peers {
namespace {

using Kernel = CGAL::Exact_predicates_inexact_constructions_kernel;
using Point = Kernel::Point_3;
using Plane = Kernel::Plane_3;
using Mesh = CGAL::Surface_mesh<Point>;
namespace PMP = CGAL::Polygon_mesh_processing;

// TriMesh -> Surface_mesh; faces the halfedge structure refuses (non-manifold) are counted in `dropped`.
Mesh to_cgal(const TriMesh& in, uint64_t& dropped) {
  Mesh out;
  out.reserve(Mesh::size_type(in.positions.size()), Mesh::size_type(3 * in.triangles.size() / 2),
              Mesh::size_type(in.triangles.size()));
  std::vector<Mesh::Vertex_index> vertex(in.positions.size());
  for (size_t i = 0; i < in.positions.size(); ++i) {
    const Vec3d& p = in.positions[i];
    vertex[i] = out.add_vertex(Point(p.x(), p.y(), p.z()));
  }
  dropped = 0;
  for (const Tri& t : in.triangles) {
    if (out.add_face(vertex[t[0]], vertex[t[1]], vertex[t[2]]) == Mesh::null_face()) ++dropped;
  }
  return out;
}

// Surface_mesh -> TriMesh over live elements (removed ones skipped); polygons are fanned.
TriMesh from_cgal(const Mesh& m) {
  TriMesh out;
  // Compact vertex ids: num_vertices() counts removed vertices too.
  std::vector<uint32_t> index(m.num_vertices(), UINT32_MAX);
  for (Mesh::Vertex_index v : m.vertices()) {
    index[v.idx()] = uint32_t(out.positions.size());
    const Point& p = m.point(v);
    out.positions.emplace_back(p.x(), p.y(), p.z());
  }
  std::vector<uint32_t> polygon;
  for (Mesh::Face_index f : m.faces()) {
    polygon.clear();
    for (Mesh::Vertex_index v : CGAL::vertices_around_face(m.halfedge(f), m)) polygon.push_back(index[v.idx()]);
    for (size_t k = 1; k + 1 < polygon.size(); ++k) out.triangles.push_back({polygon[0], polygon[k], polygon[k + 1]});
  }
  return out;
}

// One side of the cut: the part of the mesh on the negative side of a plane.
struct Side {
  TriMesh mesh;         // output, triangulated
  double clip_ms = 0.0;
  bool clip_ok = false;  // clip() returned true (manifold output)
  bool closed = false;   // CGAL::is_closed on the output
  std::string failure;   // empty when clip() returned true without throwing
};

// Clips a fresh copy of `source` (the copy is not timed) and converts the result.
Side clip_side(const Mesh& source, const Plane& plane) {
  Side side;
  Mesh mesh = source;
  try {
    const auto start = std::chrono::steady_clock::now();
    side.clip_ok = PMP::clip(mesh, plane, CGAL::parameters::clip_volume(true));
    side.clip_ms = ms_since(start);
  } catch (const std::exception& e) {
    side.failure = std::string("clip threw: ") + e.what();
    return side;
  }
  if (!side.clip_ok) side.failure = "clip returned false (output not manifold)";
  // Cap faces can come out as polygons: triangulate before measuring.
  if (!CGAL::is_triangle_mesh(mesh)) PMP::triangulate_faces(mesh);
  side.closed = CGAL::is_closed(mesh);
  side.mesh = from_cgal(mesh);
  return side;
}

// The angle summary columns of one triangle group in the CSV ("angles_cap_min_angle_deg", ...).
void add_angle_columns(CsvRow& row, const std::string& group, const AngleStats& s) {
  const std::string p = "angles_" + group;
  row.add(p + "_triangles", uint64_t(s.triangles));
  row.add(p + "_degenerate", uint64_t(s.degenerate));
  row.add(p + "_min_angle_deg", s.min_angle_deg);
  row.add(p + "_max_angle_deg", s.max_angle_deg);
  row.add(p + "_mean_min_angle_deg", s.mean_min_angle_deg);
  row.add(p + "_fraction_min_le_10", s.fraction_min_le_10);
  row.add(p + "_fraction_max_ge_160", s.fraction_max_ge_160);
}

}  // namespace

std::string run_clip(const ClipOptions& options) {
  // Input and the plane of divvox's bench cut: normal +y at `height` of the box.
  const TriMesh input = load_input(options.mesh);
  make_output_dir(options.out_dir);
  const Aabb box = mesh_bounds(input);
  const Vec3d extent = box.extent();
  const double y0 = box.min.y() + options.height * extent.y();
  const Vec3d plane_point(0.5 * (box.min.x() + box.max.x()), y0, 0.5 * (box.min.z() + box.max.z()));
  const double on_plane_tolerance = 1e-9 * extent.maxCoeff();
  const Plane lower_plane(0.0, 1.0, 0.0, -y0);  // keeps y < y0
  const Plane upper_plane(0.0, -1.0, 0.0, y0);  // keeps y > y0

  // Timed repeats: conversion, then each side clipped on its own copy.
  std::vector<double> convert_ms, lower_ms, upper_ms, both_ms;
  uint64_t dropped_faces = 0;
  Side lower, upper;
  std::string status = "ok";
  for (int r = 0; r < options.repeats; ++r) {
    const auto start = std::chrono::steady_clock::now();
    const Mesh source = to_cgal(input, dropped_faces);
    convert_ms.push_back(ms_since(start));
    lower = clip_side(source, lower_plane);
    upper = clip_side(source, upper_plane);
    lower_ms.push_back(lower.clip_ms);
    upper_ms.push_back(upper.clip_ms);
    both_ms.push_back(lower.clip_ms + upper.clip_ms);
    if (status == "ok" && !lower.failure.empty()) status = "failed: lower: " + lower.failure;
    if (status == "ok" && !upper.failure.empty()) status = "failed: upper: " + upper.failure;
  }

  // Both sides in one triangle list (upper after lower) for the angle statistics.
  TriMesh both = lower.mesh;
  const uint32_t upper_offset = uint32_t(both.positions.size());
  both.positions.insert(both.positions.end(), upper.mesh.positions.begin(), upper.mesh.positions.end());
  for (const Tri& t : upper.mesh.triangles) {
    both.triangles.push_back({t[0] + upper_offset, t[1] + upper_offset, t[2] + upper_offset});
  }
  const size_t lower_triangles = lower.mesh.triangles.size();

  // Classify: cap = all three vertices on the plane, band = some but not all (split originals).
  std::vector<uint32_t> cap, band, cut_surface;
  uint64_t cap_count[2] = {0, 0}, band_count[2] = {0, 0};
  for (uint32_t t = 0; t < both.triangles.size(); ++t) {
    int on = 0;
    for (uint32_t v : both.triangles[t]) on += std::abs(both.positions[v].y() - y0) <= on_plane_tolerance;
    const int side = t < lower_triangles ? 0 : 1;
    if (on == 3) {
      cap.push_back(t);
      ++cap_count[side];
    } else if (on > 0) {
      band.push_back(t);
      ++band_count[side];
    }
    if (on > 0) cut_surface.push_back(t);
  }
  const AngleStats angles_cap = angle_stats(both.positions, both.triangles, &cap);
  const AngleStats angles_band = angle_stats(both.positions, both.triangles, &band);
  const AngleStats angles_cut = angle_stats(both.positions, both.triangles, &cut_surface);
  const AngleStats angles_all = angle_stats(both.positions, both.triangles);
  const AngleStats angles_input = angle_stats(input.positions, input.triangles);

  // Per-side JSON and CSV columns.
  const std::string name = std::filesystem::path(options.mesh).filename().string();
  CsvRow row;
  row.add("mesh", name);
  row.add("height", options.height);
  row.add("repeats", uint64_t(options.repeats));
  row.add("input_triangles", uint64_t(input.triangles.size()));
  row.add("convert_ms", median(convert_ms));
  row.add("clip_lower_ms", median(lower_ms));
  row.add("clip_upper_ms", median(upper_ms));
  row.add("clip_both_ms", median(both_ms));
  nlohmann::json sides = nlohmann::json::array();
  const Side* side_results[2] = {&lower, &upper};
  const char* side_names[2] = {"lower", "upper"};
  for (int s = 0; s < 2; ++s) {
    const Side& side = *side_results[s];
    const SurfaceStats stats = surface_stats(side.mesh);
    sides.push_back({{"side", side_names[s]},
                     {"triangles", side.mesh.triangles.size()},
                     {"closed", side.closed},
                     {"components", stats.components},
                     {"boundary_edges", stats.boundary_edges},
                     {"nonmanifold_edges", stats.nonmanifold_edges},
                     {"volume", stats.volume},
                     {"cap_triangles", cap_count[s]},
                     {"band_triangles", band_count[s]},
                     {"clip_ok", side.clip_ok}});
    const std::string p = side_names[s];
    row.add(p + "_triangles", uint64_t(side.mesh.triangles.size()));
    row.add(p + "_closed", side.closed);
    row.add(p + "_components", uint64_t(stats.components));
    row.add(p + "_cap_triangles", cap_count[s]);
    row.add(p + "_band_triangles", band_count[s]);
  }
  add_angle_columns(row, "cap", angles_cap);
  add_angle_columns(row, "band", angles_band);
  add_angle_columns(row, "cut_surface", angles_cut);
  add_angle_columns(row, "all", angles_all);
  add_angle_columns(row, "input", angles_input);
  row.add("status", status);

  // The report: JSON plus the one-row CSV beside it.
  const nlohmann::json report = {
      {"tool", "cgal_clip"},
      {"cgal_version", CGAL_VERSION_STR},
      {"mesh", name},
      {"plane", {{"point", {plane_point.x(), plane_point.y(), plane_point.z()}}, {"normal", {0, 1, 0}}}},
      {"height", options.height},
      {"repeats", options.repeats},
      {"input_triangles", input.triangles.size()},
      {"input_volume", signed_volume(input)},
      {"convert_dropped_faces", dropped_faces},
      {"on_plane_tolerance", on_plane_tolerance},
      {"convert_ms", median(convert_ms)},
      {"clip_lower_ms", median(lower_ms)},
      {"clip_upper_ms", median(upper_ms)},
      {"clip_both_ms", median(both_ms)},
      {"sides", sides},
      {"angles",
       {{"cap", angle_stats_json(angles_cap)},
        {"band", angle_stats_json(angles_band)},
        {"cut_surface", angle_stats_json(angles_cut)},
        {"all", angle_stats_json(angles_all)},
        {"input", angle_stats_json(angles_input)}}},
      {"status", status}};
  const std::filesystem::path out(options.out_dir);
  write_json_file((out / "peers_clip.json").string(), report);
  write_text_file((out / "peers_clip.csv").string(), csv_text({row}));
  if (status != "ok") std::fprintf(stderr, "divvox_peers: clip %s: %s\n", name.c_str(), status.c_str());
  return (out / "peers_clip.json").string();
}

}  // namespace dvx::peers
