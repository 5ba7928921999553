// The surface renderer shared by the headless (EGL) and window (GLFW) modes: draws the organ
// surface into an offscreen framebuffer (lit, two-sided, cut faces in their own colour, optional
// wireframe) and reads the image back. Needs a current GL 4.5 context (egl_context.h or GLFW);
// it never creates one.
//
// Usage: renderer_init once, renderer_upload whenever the surface changed (only the dirty slot
// ranges travel), renderer_draw per frame, then renderer_read_pixels (headless) or
// renderer_blit (window), renderer_destroy with the context still current. Without multisampling
// the window either keeps the offscreen image as a scene cache, redrawn only when the scene changed
// and copied into its back buffer every frame (renderer_present), or draws straight into its back
// buffer (renderer_init's `direct`): no offscreen target and no copy, but a full draw per frame.
#pragma once

#include "render/camera.h"
#include "sim/surface_mesh.h"

#include <cstdint>
#include <string>
#include <vector>

namespace dvx {

// Per-triangle flags (RenderMesh::triangle_flags).
constexpr uint8_t kTriangleCut = 1;   // the triangle lies on a cut surface (drawn in cut_color)
constexpr uint8_t kTriangleDead = 2;  // set by the renderer for unused slots; callers need not set it

// The surface to draw, borrowed for the duration of renderer_upload: a plain view over the
// caller's arrays (a SurfaceMesh, a CutSurface's slots or a deformed snapshot), so the renderer knows
// nothing of how they were made.
//
// Triangle slots may be dead (kDeadIndex x3, as CutSurface keeps freed slots): they draw nothing.
// The dirty ranges say which slots changed since the previous upload; `full` (or a count beyond
// what the GPU buffers hold, or the renderer's first upload) uploads everything. With normals, the
// vertex range must also cover vertices whose normal changed because a neighbour moved.
struct RenderMesh {
  const Vec3f* positions = nullptr;       // (vertex_count)
  const Vec3f* normals = nullptr;         // (vertex_count) unit vertex normals; nullptr: flat shading
  const Vec3f* cut_normals = nullptr;     // (vertex_count) with `normals`: the cut faces' own (render/normals.h)
  uint32_t vertex_count = 0;
  const Tri* triangles = nullptr;         // (triangle_count) counter-clockwise seen from outside
  uint32_t triangle_count = 0;
  const uint8_t* triangle_flags = nullptr;  // (triangle_count) kTriangleCut bits; nullptr: none cut
  uint32_t vertex_begin = 0, vertex_end = 0;      // dirty vertex slots [begin, end)
  uint32_t triangle_begin = 0, triangle_end = 0;  // dirty triangle slots [begin, end)
  bool full = true;                               // ignore the ranges, upload every slot
  // No `normals`: the GPU computes smooth normals once per upload (compute shaders, render/normals.h's
  // area-weighted and smoothed normals, the cut faces and the outer surface separately, so cut rims
  // stay crisp creases). False (and no normals): flat shading.
  bool gpu_normals = false;
};

// A whole SurfaceMesh (full upload). `normals` / `flags` may be null or sized like the mesh.
RenderMesh render_mesh_of(const SurfaceMesh& mesh, const std::vector<Vec3f>* normals = nullptr,
                          const std::vector<uint8_t>* flags = nullptr);

// A scene's contact plane drawn as a tray: a square `half_size` around `centre` (a point on the plane)
// with a darker lip, and the surface's shadow on it: the deformed surface's triangles projected onto
// the plane along the key light into a small grid on the CPU (tray_shadow_grid), blurred by a
// penumbra, and sampled by the tray's own fragment shader. Part of the tray itself, so it cannot
// z-fight it, and it costs no second pass of the GPU over the surface's triangles (on llvmpipe a
// projected-geometry shadow, drawn again with a flattening matrix and a stencil, cost ~30 % of the
// frame).
struct TrayPlane {
  Vec3f centre = Vec3f::Zero(), normal = Vec3f::UnitY();
  float half_size = 1.0f;
};

// The tray of a plane (a point on it, its unit normal) under an object's bounds: centred below the
// bounds' centre, three times as wide as the object (half size 1.5 x its largest extent): a piece cut
// off and fallen from the object lands within that (the default recording's severed head top comes to
// rest 11 units from the centre of the 9.9-unit bunny; at 0.8 x it lay half off the tray). The window
// and the headless frames draw the same trays.
TrayPlane tray_under(const Vec3f& bounds_min, const Vec3f& bounds_max, const Vec3f& plane_point,
                     const Vec3f& plane_normal);

// The cells [x0, x1) x [y0, y1) of the shadow grid that the tray samples (tray_shadow_box): empty
// when x0 >= x1.
struct ShadowBox {
  int x0 = 0, y0 = 0, x1 = 0, y1 = 0;
};

// The tray shadow's working arrays (tray_shadow_grid).
struct ShadowScratch {
  std::vector<Vec3f> projected;             // (vertex slots) cell x, cell y, height above the tray
  std::vector<float> area, height;          // (cells) projected area (cells^2), its height sum
  std::vector<float> radius, blurred;       // (cells) the penumbra's half-width, the first blur
  std::vector<double> table, height_table;  // summed-area tables ((g + 1)^2)
};

struct DrawOptions {
  // Clear the view first (colour and depth). False: the caller cleared it (the window clears its
  // whole back buffer at once: on a software rasteriser a clear of a part of it draws a quad).
  bool clear = true;
  bool wireframe = false;                         // overlay the triangle edges
  std::vector<TrayPlane> trays;                   // drawn after the surface (none: no ground)
  bool shadows = true;                            // the surface's shadow on the trays
  // Skip back faces (the surface is closed, so none is visible from outside): on a software
  // rasteriser, where triangle setup dominates, it saves about half the draw.
  bool cull_back_faces = false;
  // With cull_back_faces: the tissue's lights evaluated per vertex and interpolated, not per pixel
  // (render/renderer_shaders.inc: VERTEX_LIT). For a software rasteriser, where the liver's triangles
  // cover a few pixels and each is shaded in whole 4x4 blocks: a new image costs its threads ~10 % less.
  bool vertex_lighting = false;
  // The outer surface drawn in this many pieces, each flushed to the rasteriser at once: a software
  // rasteriser (llvmpipe) sets triangles up on the calling thread and rasterises only on a flush,
  // so in one piece its rasteriser threads wait for the whole setup, in several they rasterise one
  // piece while the next is set up.
  int surface_pieces = 1;
  // Draw only the outer surface's pieces [pieces_begin, pieces_end): the clear with the first piece,
  // the cut faces and the wireframe with the last. A window can so spread one image over two frames
  // (renderer_double_buffer).
  int pieces_begin = 0, pieces_end = 64;
  Vec3f surface_color = Vec3f(0.88f, 0.70f, 0.64f);  // pale organ capsule
  Vec3f cut_color = Vec3f(0.56f, 0.17f, 0.12f);      // the cut faces' parenchyma: deep red-brown liver tissue
  Vec3f wire_color = Vec3f(0.20f, 0.12f, 0.12f);
  Vec3f background = Vec3f(0.15f, 0.16f, 0.19f);
  Vec3f tray_color = Vec3f(0.55f, 0.60f, 0.64f);  // brushed steel
  float shadow_alpha = 0.65f;                     // how much the shadow darkens the tray
};

// GL object names and the capacities of the GPU buffers.
//
// Why this layout: vertex slots and triangle slots are stable (CutSurface reuses freed slots and
// appends new ones), so the GPU buffers mirror the caller's slot arrays one to one and a cut step
// only rewrites the few slots it touched. Buffers grow geometrically, and only a growth forces a
// full upload. Dead triangle slots are written as {0,0,0} (zero area, no fragments), which keeps
// every live triangle at its slot so gl_PrimitiveID equals the slot index; the wireframe pass and
// the GPU normal passes read the triangle's flags from a byte array in a shader storage buffer
// indexed by it (an SSBO rather than a texture buffer: its guaranteed size, 128 MiB, covers any
// surface, where a texture buffer is only guaranteed 64 Ki texels). The lit passes instead draw the
// outer surface and the cut faces from two index buffers (the outer one mirroring the slots, the
// cut faces packed) with the class as a uniform. Either way flat per-triangle data needs no
// duplicated vertices along the rim of a cut, where a cut face and the outer surface share vertices.
struct Renderer {
  // Offscreen target: `framebuffer` is drawn into (multisampled when samples > 0), and
  // `resolve_framebuffer` holds the single-sample image read back or blitted (== framebuffer
  // when samples == 0). `direct`: none; framebuffer 0 (the window's back buffer, which must have
  // a depth buffer) is drawn into at (origin_x, origin_y): on a software rasteriser the copy of the
  // image into the window cost as much as the tray.
  int width = 0, height = 0, samples = 0;
  bool direct = false;
  int origin_x = 0, origin_y = 0;
  // renderer_present copied the image into framebuffer 0 at the origin: until the next draw, the
  // view (renderer_target, renderer_read_pixels) is that rectangle of framebuffer 0.
  bool presented = false;
  // renderer_double_buffer: a second target holds the image shown (renderer_present copies it)
  // while the next is drawn into the first; renderer_show_drawn swaps them.
  bool double_buffered = false;
  uint32_t shown_framebuffer = 0, shown_color_renderbuffer = 0, shown_depth_texture = 0;
  uint32_t framebuffer = 0, color_renderbuffer = 0, depth_renderbuffer = 0;
  uint32_t depth_texture = 0;  // the depth attachment when single-sampled (instead of depth_renderbuffer)
  uint32_t resolve_framebuffer = 0, resolve_renderbuffer = 0;
  // Programs: the lit surface's variants (index 2 * flat + cut faces, 4 + cut faces lit per vertex:
  // see kSurfaceFragmentShader), the wireframe overlay.
  uint32_t surface_programs[6] = {0, 0, 0, 0, 0, 0};
  uint32_t wire_program = 0;
  // Trays and shadows (render/tray.cpp): the tray's quad comes from gl_VertexID (an empty vertex
  // array); the shadow re-draws the surface's index buffer, flattened onto the plane.
  // tray_program samples the shadow, tray_flat_program does not (render/tray.cpp).
  uint32_t tray_program = 0, tray_flat_program = 0, empty_vertex_array = 0, shadow_texture = 0;
  bool shadow_valid = false;  // shadow_texture holds the first tray's shadow for this frame
  ShadowBox shadow_box;       // the cells around the shadow (tray_shadow_box); the rest of the tray is drawn flat
  std::vector<float> shadow_grid;
  ShadowScratch shadow_scratch;
  // The triangle slots of the last upload (dead ones {0,0,0}), for the shadow's projected areas.
  std::vector<Tri> shadow_triangles;
  std::vector<uint8_t> shadow_bytes;
  // Mesh buffers, mirroring the caller's slots.
  uint32_t vertex_array = 0;
  uint32_t position_buffer = 0;  // (vertex_capacity x 3 floats)
  uint32_t normal_buffer = 0;    // (vertex_capacity x 3 floats)
  uint32_t index_buffer = 0;     // (triangle_capacity x 3 uint32)
  // The triangles split by class for the lit passes: the outer surface's (the same slots, cut and
  // dead ones degenerate) and the cut faces' (packed, below), so the fragment shader knows a
  // triangle's class from a uniform: reading the flags by gl_PrimitiveID makes llvmpipe run its
  // primitive assembler, which grows its output one realloc per triangle (~20 % of the render
  // thread at 128). The cut faces' buffer is not a mirror: it holds the cut_count live cut faces
  // packed from 0 (a mirror made the cut pass submit, as degenerate triangles, every slot between
  // the first and the last cut face: after a few cuts most of the surface).
  uint32_t outer_index_buffer = 0, cut_index_buffer = 0;
  uint32_t cut_count = 0;
  uint32_t flag_buffer = 0;      // (triangle_capacity bytes, rounded up to 4) SSBO binding 0
  // GPU normals (render/normals.h's, computed the same way), in passes without atomics (so the sums
  // do not depend on scheduling): per triangle slot, its face's cross product at each corner
  // (corner_normal_buffer, 3 corners x 3 floats); then per vertex slot, the sums over the corners it
  // is part of (the vertex -> corner adjacency, CSR, rebuilt on the CPU when triangles change: only
  // on cut steps), normalised, the outer surface's into normal_buffer and the cut faces' into
  // cut_normal_buffer; then kNormalSmoothingPasses times: per triangle slot, |face| times the sum of
  // its vertices' normals of its class at each corner, and the per-vertex pass again. Each fragment
  // takes the normal of its triangle's class, so cut rims stay creases.
  uint32_t cut_normal_buffer = 0;     // (vertex_capacity x 3 floats)
  uint32_t corner_normal_buffer = 0;  // (triangle_capacity x 9 floats)
  uint32_t adjacency_offset_buffer = 0, adjacency_buffer = 0;  // (vertex_capacity + 1), (3 x triangle_capacity) uint32
  uint32_t triangle_normal_program = 0, vertex_normal_program = 0, smooth_normal_program = 0;
  std::vector<uint32_t> scratch_offsets, scratch_adjacency, scratch_fill;
  bool adjacency_stale = true;
  bool gpu_normals = false, normals_stale = false;
  bool split_normals = false;  // cut faces have their own normals (GPU-computed or given)
  uint32_t vertex_capacity = 0, triangle_capacity = 0;
  uint32_t vertex_count = 0, triangle_count = 0;
  bool has_normals = false;
  bool uploaded = false;           // false until the first upload (which is always full)
  uint64_t last_upload_bytes = 0;  // bytes sent by the last renderer_upload (tests, stats)
  // Scratch for the converted triangle range (dead slots degenerated, flags with kTriangleDead).
  std::vector<Tri> scratch_triangles, scratch_outer, scratch_cut;
  std::vector<uint8_t> scratch_flags;
};

// Creates the programs, the mesh buffers and a width x height offscreen target (RGBA8 colour,
// 24-bit depth; `samples` > 0 multisamples it), or with `direct` (samples must be 0) none: it
// draws into framebuffer 0 at renderer_place's origin. Returns false with a one-line reason.
bool renderer_init(Renderer& r, int width, int height, std::string& error, int samples = 0, bool direct = false);
// Direct mode and renderer_present: where in framebuffer 0 the image's lower-left corner lies (GL's
// convention: y up).
void renderer_place(Renderer& r, int x, int y);
// Where the renderer draws: its framebuffer and the rectangle in it (for overlays drawn on top).
struct ViewTarget {
  uint32_t framebuffer = 0;
  int x = 0, y = 0, width = 0, height = 0;
  // Nonzero after renderer_present: the scene's depth is not in the framebuffer's depth buffer
  // (that holds only what is drawn after the copy) but in this texture, the view's pixel (i, j) at
  // texel (i - x, j - y); what is drawn over the scene tests against it in its fragment shader.
  uint32_t scene_depth = 0;
};
ViewTarget renderer_target(const Renderer& r);
// Recreates the offscreen target at a new size (window resize); the mesh stays.
bool renderer_resize(Renderer& r, int width, int height, std::string& error);
// Sends the changed slots of `mesh` to the GPU (see RenderMesh).
void renderer_upload(Renderer& r, const RenderMesh& mesh);
// Runs the GPU normal passes when an upload made them stale (renderer_draw calls it too; calling it
// first lets a caller time it on its own).
void renderer_update_normals(Renderer& r);
// Draws the uploaded surface and the trays into the offscreen target (direct mode: the window's).
void renderer_draw(Renderer& r, const Camera& camera, const DrawOptions& options);
// renderer_draw in two halves: the (cleared) view and the surface, then tray_draw (after
// tray_shadow_update), so a caller can do its own work in between while the surface rasterises.
void renderer_draw_surface(Renderer& r, const Camera& camera, const DrawOptions& options);
// Trays (render/tray.cpp): creates / deletes their program and shadow texture (renderer_init /
// renderer_destroy call them); draws options.trays into the renderer's target, after the surface.
bool tray_init(Renderer& r, std::string& error);
void tray_destroy(Renderer& r);
void tray_draw(Renderer& r, const Camera& camera, const DrawOptions& options);
// The shadow of the surface at `positions` (count vertex slots; non-finite ones skipped) on the
// first tray, for this frame's camera (the light is the camera's key light). Call it before
// renderer_draw when the surface or the camera changed; without it the tray has no shadow. When
// `positions` are the vertex slots of the mesh last uploaded (count == its vertex count), its
// triangles (kept by renderer_upload) cast the shadow by their projected areas; else each vertex
// darkens its cell of the grid.
void tray_shadow_update(Renderer& r, const Vec3f* positions, uint32_t count, const Camera& camera,
                        const DrawOptions& options);
// The shadow grid (no GL): kTrayShadowGrid^2 cells over the tray's square, row-major along the
// tray's axes, each the share of the light the surface blocks, in [0, 1]. The triangles' areas
// projected along `light` onto the plane, half of it counted (a closed surface covers its shadow
// twice): the share of each cell in the shadow, so a piece smaller than a cell darkens it only in
// part (without triangles, each vertex covers its whole cell). Then blurred twice by a box whose
// half-width is the penumbra's: one cell plus kTrayPenumbra x the occluders' mean height above the
// tray (within 6 cells), up to 10 cells: sharp where a piece lies on the tray, soft under the organ
// hanging over it, and a small piece's shadow is as small and as faint as the piece. (The grid
// once marked every vertex's cell in full and dilated the marks, so a crumb of one voxel cast a
// dark blob of 5 x 5 cells, a sixth of the organ's size.)
constexpr int kTrayShadowGrid = 128;
constexpr float kTrayPenumbra = 0.15f;  // the penumbra's half-width per unit of height (a ~9 degree light)
void tray_shadow_grid(const Vec3f* positions, uint32_t count, const Tri* triangles, uint32_t triangle_count,
                      const TrayPlane& tray, const Vec3f& light, std::vector<float>& grid, ShadowScratch& scratch);
// The rectangle of a g x g grid of shadow bytes (row-major) around its nonzero cells, grown by one cell
// (the bilinear fetch reaches half a cell past them) and cut to the grid; empty when all are 0.
// Outside it the tray is drawn without sampling the shadow.
ShadowBox tray_shadow_box(const uint8_t* cells, int g);
// Reads the last image: width x height RGBA8, row 0 the top of the image. False on a GL error.
// Direct mode (and after renderer_present): the back buffer's rectangle, so before the swap
// (including what was drawn over it since).
bool renderer_read_pixels(Renderer& r, std::vector<uint8_t>& rgba);
// Copies the last image into another framebuffer (0: the window's), scaled to w x h, its lower-left
// corner at (x, y) of the target (GL's convention: y up). Direct mode: nothing to copy.
void renderer_blit(Renderer& r, uint32_t target_framebuffer, int width, int height, int x = 0, int y = 0);
// The window's scene cache (single-sampled offscreen target): copies the image's colour into
// framebuffer 0 at renderer_place's origin; until the next renderer_draw_surface the view is that
// rectangle of framebuffer 0, with the scene's depth in ViewTarget::scene_depth (a depth blit cost
// llvmpipe as much as the colour's; the window's overlays test against the texture and order
// themselves far to near, so the window need not even clear its depth buffer). A window redraws an
// unchanged scene (no new snapshot, the camera still) by this copy alone: on llvmpipe a fifth of
// drawing the surface again.
void renderer_present(Renderer& r);
// Single-sampled offscreen mode: keeps a second target, the image shown, so an image can be drawn
// over several frames (DrawOptions::pieces_begin / pieces_end) while the last one is presented.
// False (nothing changed) in direct or multisampled mode, or with the resize's error.
bool renderer_double_buffer(Renderer& r, std::string& error);
// Double-buffered: the image just drawn becomes the one shown (renderer_present, ViewTarget::scene_depth).
void renderer_show_drawn(Renderer& r);
// Deletes every GL object (the context must still be current).
void renderer_destroy(Renderer& r);

// Drains glGetError: false with the error names when there were any.
bool gl_check_errors(std::string& error);

// Writes an RGBA8 image (row 0 the top) as PNG. False with a one-line reason naming the file.
bool write_png(const std::string& path, int width, int height, const std::vector<uint8_t>& rgba,
               std::string& error);

}  // namespace dvx
