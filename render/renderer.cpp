#include "render/renderer.h"

#include "render/gl_program.h"
#include "render/normals.h"

#include <glad/gl.h>

#include <algorithm>
#include <cstdio>
#include <cstring>

namespace dvx {

static_assert(sizeof(Vec3f) == 3 * sizeof(float), "positions are uploaded as packed float triples");
static_assert(sizeof(Tri) == 3 * sizeof(uint32_t), "triangles are uploaded as packed uint32 triples");

namespace {

// Smallest buffer capacities (slots), so an empty mesh still has vertex 0 for dead triangles to use.
constexpr uint32_t kMinVertexCapacity = 1024;
constexpr uint32_t kMinTriangleCapacity = 2048;

#include "render/renderer_shaders.inc"

// Something to draw into: the offscreen target, or framebuffer 0 in direct mode.
bool has_target(const Renderer& r) { return r.framebuffer != 0 || r.direct; }

// Deletes the offscreen target's objects.
void destroy_target(Renderer& r) {
  if (r.resolve_framebuffer && r.resolve_framebuffer != r.framebuffer) glDeleteFramebuffers(1, &r.resolve_framebuffer);
  if (r.framebuffer) glDeleteFramebuffers(1, &r.framebuffer);
  if (r.color_renderbuffer) glDeleteRenderbuffers(1, &r.color_renderbuffer);
  if (r.depth_renderbuffer) glDeleteRenderbuffers(1, &r.depth_renderbuffer);
  if (r.resolve_renderbuffer) glDeleteRenderbuffers(1, &r.resolve_renderbuffer);
  if (r.depth_texture) glDeleteTextures(1, &r.depth_texture);
  r.depth_texture = 0;
  if (r.shown_framebuffer) glDeleteFramebuffers(1, &r.shown_framebuffer);
  if (r.shown_color_renderbuffer) glDeleteRenderbuffers(1, &r.shown_color_renderbuffer);
  if (r.shown_depth_texture) glDeleteTextures(1, &r.shown_depth_texture);
  r.shown_framebuffer = r.shown_color_renderbuffer = r.shown_depth_texture = 0;
  r.framebuffer = r.resolve_framebuffer = 0;
  r.color_renderbuffer = r.depth_renderbuffer = r.resolve_renderbuffer = 0;
}

// Creates the offscreen target at r.width x r.height with r.samples.
bool create_target(Renderer& r, std::string& error) {
  GLint max_size = 0, max_samples = 0;
  glGetIntegerv(GL_MAX_RENDERBUFFER_SIZE, &max_size);
  glGetIntegerv(GL_MAX_SAMPLES, &max_samples);
  if (r.width < 1 || r.height < 1 || r.width > max_size || r.height > max_size) {
    error = "GL: image size " + std::to_string(r.width) + "x" + std::to_string(r.height) +
            " outside 1.." + std::to_string(max_size);
    return false;
  }
  r.samples = std::clamp(r.samples, 0, int(max_samples));
  if (r.direct) {  // framebuffer 0: nothing to create
    r.samples = 0;
    return true;
  }
  // Drawn-into framebuffer: RGBA8 colour + 24-bit depth, multisampled when asked.
  glCreateRenderbuffers(1, &r.color_renderbuffer);
  if (r.samples > 0) glCreateRenderbuffers(1, &r.depth_renderbuffer);
  glNamedRenderbufferStorageMultisample(r.color_renderbuffer, r.samples, GL_RGBA8, r.width, r.height);
  // Single-sampled, the depth is a texture (ViewTarget::scene_depth: the window's overlays test
  // against it after renderer_present, which copies only the colour).
  if (r.samples == 0) {
    glCreateTextures(GL_TEXTURE_2D, 1, &r.depth_texture);
    glTextureStorage2D(r.depth_texture, 1, GL_DEPTH_COMPONENT24, r.width, r.height);
    glTextureParameteri(r.depth_texture, GL_TEXTURE_MIN_FILTER, GL_NEAREST);
    glTextureParameteri(r.depth_texture, GL_TEXTURE_MAG_FILTER, GL_NEAREST);
  } else {
    glNamedRenderbufferStorageMultisample(r.depth_renderbuffer, r.samples, GL_DEPTH_COMPONENT24, r.width, r.height);
  }
  glCreateFramebuffers(1, &r.framebuffer);
  glNamedFramebufferRenderbuffer(r.framebuffer, GL_COLOR_ATTACHMENT0, GL_RENDERBUFFER, r.color_renderbuffer);
  if (r.depth_texture) {
    glNamedFramebufferTexture(r.framebuffer, GL_DEPTH_ATTACHMENT, r.depth_texture, 0);
  } else {
    glNamedFramebufferRenderbuffer(r.framebuffer, GL_DEPTH_ATTACHMENT, GL_RENDERBUFFER, r.depth_renderbuffer);
  }
  // Double-buffered (single-sampled only): a second colour + depth target for the image shown.
  if (r.double_buffered && r.samples == 0) {
    glCreateRenderbuffers(1, &r.shown_color_renderbuffer);
    glNamedRenderbufferStorage(r.shown_color_renderbuffer, GL_RGBA8, r.width, r.height);
    glCreateTextures(GL_TEXTURE_2D, 1, &r.shown_depth_texture);
    glTextureStorage2D(r.shown_depth_texture, 1, GL_DEPTH_COMPONENT24, r.width, r.height);
    glTextureParameteri(r.shown_depth_texture, GL_TEXTURE_MIN_FILTER, GL_NEAREST);
    glTextureParameteri(r.shown_depth_texture, GL_TEXTURE_MAG_FILTER, GL_NEAREST);
    glCreateFramebuffers(1, &r.shown_framebuffer);
    glNamedFramebufferRenderbuffer(r.shown_framebuffer, GL_COLOR_ATTACHMENT0, GL_RENDERBUFFER, r.shown_color_renderbuffer);
    glNamedFramebufferTexture(r.shown_framebuffer, GL_DEPTH_ATTACHMENT, r.shown_depth_texture, 0);
    const float clear[4] = {0.0f, 0.0f, 0.0f, 1.0f};
    glClearNamedFramebufferfv(r.shown_framebuffer, GL_COLOR, 0, clear);
    glClearNamedFramebufferfi(r.shown_framebuffer, GL_DEPTH_STENCIL, 0, 1.0f, 0);
  }
  // Single-sample copy for readback when multisampled.
  r.resolve_framebuffer = r.framebuffer;
  if (r.samples > 0) {
    glCreateRenderbuffers(1, &r.resolve_renderbuffer);
    glNamedRenderbufferStorage(r.resolve_renderbuffer, GL_RGBA8, r.width, r.height);
    glCreateFramebuffers(1, &r.resolve_framebuffer);
    glNamedFramebufferRenderbuffer(r.resolve_framebuffer, GL_COLOR_ATTACHMENT0, GL_RENDERBUFFER,
                                   r.resolve_renderbuffer);
  }
  const GLenum status = glCheckNamedFramebufferStatus(r.framebuffer, GL_FRAMEBUFFER);
  const GLenum resolve_status = glCheckNamedFramebufferStatus(r.resolve_framebuffer, GL_FRAMEBUFFER);
  if (status != GL_FRAMEBUFFER_COMPLETE || resolve_status != GL_FRAMEBUFFER_COMPLETE) {
    char code[16];
    std::snprintf(code, sizeof code, "0x%04X", status != GL_FRAMEBUFFER_COMPLETE ? status : resolve_status);
    error = std::string("GL: offscreen framebuffer incomplete (status ") + code + ")";
    destroy_target(r);
    return false;
  }
  return true;
}

// (Re)allocates the vertex buffers for `capacity` slots (contents undefined until uploaded).
void allocate_vertex_buffers(Renderer& r, uint32_t capacity) {
  r.vertex_capacity = capacity;
  glNamedBufferData(r.position_buffer, GLsizeiptr(capacity) * 12, nullptr, GL_DYNAMIC_DRAW);
  glNamedBufferData(r.normal_buffer, GLsizeiptr(capacity) * 12, nullptr, GL_DYNAMIC_DRAW);
  glNamedBufferData(r.cut_normal_buffer, GLsizeiptr(capacity) * 12, nullptr, GL_DYNAMIC_DRAW);
}

// The vertex -> corner adjacency (CSR over vertex slots, corners 3t + c of live triangles) from
// the CPU's triangle slots, uploaded whole.
void rebuild_adjacency(Renderer& r, const Tri* triangles, uint32_t triangle_count, uint32_t vertex_count) {
  std::vector<uint32_t>& offsets = r.scratch_offsets;
  std::vector<uint32_t>& corners = r.scratch_adjacency;
  offsets.assign(size_t(vertex_count) + 1, 0);
  for (uint32_t t = 0; t < triangle_count; ++t) {
    const Tri& tri = triangles[t];
    if (tri[0] >= vertex_count || tri[1] >= vertex_count || tri[2] >= vertex_count) continue;
    for (uint32_t v : tri) ++offsets[v + 1];
  }
  for (uint32_t v = 0; v < vertex_count; ++v) offsets[v + 1] += offsets[v];
  corners.resize(offsets[vertex_count]);
  std::vector<uint32_t>& fill = r.scratch_fill;
  fill.assign(offsets.begin(), offsets.end() - 1);
  for (uint32_t t = 0; t < triangle_count; ++t) {
    const Tri& tri = triangles[t];
    if (tri[0] >= vertex_count || tri[1] >= vertex_count || tri[2] >= vertex_count) continue;
    for (uint32_t c = 0; c < 3; ++c) corners[fill[tri[c]]++] = 3 * t + c;
  }
  glNamedBufferData(r.adjacency_offset_buffer, GLsizeiptr(offsets.size() * 4), offsets.data(), GL_DYNAMIC_DRAW);
  glNamedBufferData(r.adjacency_buffer, GLsizeiptr(std::max<size_t>(corners.size(), 1) * 4),
                    corners.empty() ? nullptr : corners.data(), GL_DYNAMIC_DRAW);
  r.last_upload_bytes += uint64_t(offsets.size() + corners.size()) * 4;
}

// Pass 1 and 2 of the GPU normals (see Renderer), over every slot.
void compute_normals(Renderer& r) {
  glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 0, r.flag_buffer);
  glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 1, r.position_buffer);
  glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 2, r.index_buffer);
  glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 3, r.corner_normal_buffer);
  glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 4, r.normal_buffer);
  glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 5, r.cut_normal_buffer);
  glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 6, r.adjacency_offset_buffer);
  glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 7, r.adjacency_buffer);
  glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT);
  glUseProgram(r.triangle_normal_program);
  glUniform1ui(0, r.triangle_count);
  glDispatchCompute((r.triangle_count + 63) / 64, 1, 1);
  glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT);
  glUseProgram(r.vertex_normal_program);
  glUniform1ui(0, r.vertex_count);
  glDispatchCompute((r.vertex_count + 63) / 64, 1, 1);
  glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT);
  // The smoothing passes: per triangle the weighted sums of its vertices' normals, then pass 2 again.
  for (int pass = 0; pass < kNormalSmoothingPasses; ++pass) {
    glUseProgram(r.smooth_normal_program);
    glUniform1ui(0, r.triangle_count);
    glDispatchCompute((r.triangle_count + 63) / 64, 1, 1);
    glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT);
    glUseProgram(r.vertex_normal_program);
    glUniform1ui(0, r.vertex_count);
    glDispatchCompute((r.vertex_count + 63) / 64, 1, 1);
    glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT);
  }
  glMemoryBarrier(GL_VERTEX_ATTRIB_ARRAY_BARRIER_BIT | GL_SHADER_STORAGE_BARRIER_BIT);
  glUseProgram(0);
  r.normals_stale = false;
}

// (Re)allocates the index and flag buffers for `capacity` triangle slots.
void allocate_triangle_buffers(Renderer& r, uint32_t capacity) {
  r.triangle_capacity = capacity;
  glNamedBufferData(r.index_buffer, GLsizeiptr(capacity) * 12, nullptr, GL_DYNAMIC_DRAW);
  glNamedBufferData(r.outer_index_buffer, GLsizeiptr(capacity) * 12, nullptr, GL_DYNAMIC_DRAW);
  glNamedBufferData(r.cut_index_buffer, GLsizeiptr(capacity) * 12, nullptr, GL_DYNAMIC_DRAW);
  glNamedBufferData(r.flag_buffer, (GLsizeiptr(capacity) + 3) / 4 * 4, nullptr, GL_DYNAMIC_DRAW);
  glNamedBufferData(r.corner_normal_buffer, GLsizeiptr(capacity) * 36, nullptr, GL_DYNAMIC_DRAW);
}

// Capacity for `needed` slots: geometric growth so a growing cut re-uploads rarely.
uint32_t grown_capacity(uint32_t current, uint32_t needed, uint32_t minimum) {
  const uint64_t grown = std::max<uint64_t>({uint64_t(needed), uint64_t(current) + current / 2, minimum});
  return uint32_t(std::min<uint64_t>(grown, UINT32_MAX));
}

// The cut pass's index buffer: every live cut face, packed from 0 (rebuilt from all slots whenever
// triangles changed: a scan of the flags, ~0.1 ms at 92 k slots). Mirroring the slots instead
// (the other slots degenerate) made the cut pass submit every slot between the first and the last
// cut face, which after a few cuts (freed slots are reused all over) was most of the surface
// again: each degenerate triangle still costs llvmpipe's vertex stage and setup on the render thread.
void upload_cut_faces(Renderer& r, const RenderMesh& mesh) {
  std::vector<Tri>& cut = r.scratch_cut;
  cut.clear();
  if (mesh.triangle_flags) {
    for (uint32_t t = 0; t < mesh.triangle_count; ++t) {
      const Tri& tri = mesh.triangles[t];
      if ((mesh.triangle_flags[t] & kTriangleCut) == 0) continue;
      if (tri[0] >= mesh.vertex_count || tri[1] >= mesh.vertex_count || tri[2] >= mesh.vertex_count) continue;
      cut.push_back(tri);
    }
  }
  r.cut_count = uint32_t(cut.size());
  if (!cut.empty()) glNamedBufferSubData(r.cut_index_buffer, 0, GLsizeiptr(cut.size()) * 12, cut.data());
  r.last_upload_bytes += uint64_t(cut.size()) * 12;
}

}  // namespace

RenderMesh render_mesh_of(const SurfaceMesh& mesh, const std::vector<Vec3f>* normals,
                          const std::vector<uint8_t>* flags) {
  RenderMesh m;
  m.positions = mesh.positions.data();
  m.vertex_count = uint32_t(mesh.positions.size());
  m.normals = normals && normals->size() == mesh.positions.size() ? normals->data() : nullptr;
  m.triangles = mesh.triangles.data();
  m.triangle_count = uint32_t(mesh.triangles.size());
  m.triangle_flags = flags && flags->size() == mesh.triangles.size() ? flags->data() : nullptr;
  m.full = true;
  return m;
}

bool renderer_init(Renderer& r, int width, int height, std::string& error, int samples, bool direct) {
  renderer_destroy(r);
  r.width = width;
  r.height = height;
  r.samples = samples;
  r.direct = direct;
  if (!create_target(r, error)) return false;

  bool surface_ok = true;
  for (int k = 0; k < 6 && surface_ok; ++k) {
    const std::string preamble = kSurfacePreambles[k];
    r.surface_programs[k] = gl_link_program((preamble + kVertexShader).c_str(), (preamble + kSurfaceFragmentShader).c_str(), error);
    surface_ok = r.surface_programs[k] != 0;
  }
  if (surface_ok) {
    r.wire_program = gl_link_program((std::string(kSurfacePreambles[0]) + kVertexShader).c_str(), kWireFragmentShader, error);
  }
  if (r.wire_program) r.triangle_normal_program = gl_link_compute(kTriangleNormalShader, error);
  if (r.triangle_normal_program) r.vertex_normal_program = gl_link_compute(kVertexNormalShader, error);
  if (r.vertex_normal_program) r.smooth_normal_program = gl_link_compute(kSmoothNormalShader, error);
  if (!r.wire_program || !r.smooth_normal_program || !tray_init(r, error)) {
    renderer_destroy(r);
    return false;
  }

  // Mesh buffers: positions on binding 0, normals on binding 1, indices in the vertex array.
  glCreateBuffers(1, &r.position_buffer);
  glCreateBuffers(1, &r.normal_buffer);
  glCreateBuffers(1, &r.index_buffer);
  glCreateBuffers(1, &r.outer_index_buffer);
  glCreateBuffers(1, &r.cut_index_buffer);
  glCreateBuffers(1, &r.flag_buffer);
  glCreateBuffers(1, &r.cut_normal_buffer);
  glCreateBuffers(1, &r.corner_normal_buffer);
  glCreateBuffers(1, &r.adjacency_offset_buffer);
  glCreateBuffers(1, &r.adjacency_buffer);
  allocate_vertex_buffers(r, kMinVertexCapacity);
  allocate_triangle_buffers(r, kMinTriangleCapacity);
  glCreateVertexArrays(1, &r.vertex_array);
  glVertexArrayVertexBuffer(r.vertex_array, 0, r.position_buffer, 0, 12);
  glVertexArrayVertexBuffer(r.vertex_array, 1, r.normal_buffer, 0, 12);
  glVertexArrayVertexBuffer(r.vertex_array, 2, r.cut_normal_buffer, 0, 12);
  for (GLuint a = 0; a < 3; ++a) {
    glVertexArrayAttribFormat(r.vertex_array, a, 3, GL_FLOAT, GL_FALSE, 0);
    glVertexArrayAttribBinding(r.vertex_array, a, a);
  }
  glEnableVertexArrayAttrib(r.vertex_array, 0);
  glVertexArrayElementBuffer(r.vertex_array, r.index_buffer);

  std::string gl_error;
  if (!gl_check_errors(gl_error)) {
    error = "GL: renderer setup failed: " + gl_error;
    renderer_destroy(r);
    return false;
  }
  return true;
}

void renderer_place(Renderer& r, int x, int y) {
  r.origin_x = x;
  r.origin_y = y;
}

ViewTarget renderer_target(const Renderer& r) {
  if (r.presented) {
    return ViewTarget{0, r.origin_x, r.origin_y, r.width, r.height, r.shown_framebuffer ? r.shown_depth_texture : r.depth_texture};
  }
  return r.direct ? ViewTarget{0, r.origin_x, r.origin_y, r.width, r.height} : ViewTarget{r.framebuffer, 0, 0, r.width, r.height};
}

bool renderer_resize(Renderer& r, int width, int height, std::string& error) {
  destroy_target(r);
  r.presented = false;
  r.width = width;
  r.height = height;
  return create_target(r, error);
}

void renderer_upload(Renderer& r, const RenderMesh& mesh) {
  r.last_upload_bytes = 0;
  if (!r.vertex_array) return;  // not initialised
  const bool has_normals = mesh.normals != nullptr;
  const bool gpu_normals = !has_normals && mesh.gpu_normals;
  const uint32_t previous_vertex_count = r.vertex_count;
  // The first upload, growth, or a switch between smooth and flat shading re-sends everything.
  const bool split_normals = gpu_normals || (has_normals && mesh.cut_normals != nullptr);
  bool vertices_full = mesh.full || !r.uploaded || has_normals != r.has_normals || split_normals != r.split_normals;
  bool triangles_full = mesh.full || !r.uploaded;
  if (mesh.vertex_count > r.vertex_capacity) {
    allocate_vertex_buffers(r, grown_capacity(r.vertex_capacity, mesh.vertex_count, kMinVertexCapacity));
    vertices_full = true;
  }
  if (mesh.triangle_count > r.triangle_capacity) {
    allocate_triangle_buffers(r, grown_capacity(r.triangle_capacity, mesh.triangle_count, kMinTriangleCapacity));
    triangles_full = true;
  }

  // Vertex slots: positions (and normals) copied as they are.
  const uint32_t vb = vertices_full ? 0 : std::min(mesh.vertex_begin, mesh.vertex_count);
  const uint32_t ve = vertices_full ? mesh.vertex_count : std::min(mesh.vertex_end, mesh.vertex_count);
  if (vb < ve && mesh.positions) {
    const GLintptr offset = GLintptr(vb) * 12;
    const GLsizeiptr size = GLsizeiptr(ve - vb) * 12;
    glNamedBufferSubData(r.position_buffer, offset, size, mesh.positions + vb);
    if (has_normals) glNamedBufferSubData(r.normal_buffer, offset, size, mesh.normals + vb);
    if (has_normals && mesh.cut_normals) glNamedBufferSubData(r.cut_normal_buffer, offset, size, mesh.cut_normals + vb);
    r.last_upload_bytes += uint64_t(size) * (has_normals ? (mesh.cut_normals ? 3 : 2) : 1);
  }

  // Triangle slots: dead ones (or ones naming a vertex that does not exist) become {0,0,0} with
  // the dead flag, so they rasterise nothing and every slot keeps its gl_PrimitiveID.
  const uint32_t tb = triangles_full ? 0 : std::min(mesh.triangle_begin, mesh.triangle_count);
  const uint32_t te = triangles_full ? mesh.triangle_count : std::min(mesh.triangle_end, mesh.triangle_count);
  if (tb < te && mesh.triangles) {
    const uint32_t n = te - tb;
    r.scratch_triangles.resize(n);
    r.scratch_outer.resize(n);
    r.scratch_flags.resize(n);
    for (uint32_t i = 0; i < n; ++i) {
      const Tri& t = mesh.triangles[tb + i];
      const bool dead = t[0] >= mesh.vertex_count || t[1] >= mesh.vertex_count || t[2] >= mesh.vertex_count;
      const uint8_t flags = mesh.triangle_flags ? uint8_t(mesh.triangle_flags[tb + i] & kTriangleCut) : 0;
      const bool cut = !dead && flags != 0;
      r.scratch_triangles[i] = dead ? Tri{0, 0, 0} : t;
      r.scratch_outer[i] = dead || cut ? Tri{0, 0, 0} : t;
      r.scratch_flags[i] = dead ? kTriangleDead : flags;
    }
    glNamedBufferSubData(r.index_buffer, GLintptr(tb) * 12, GLsizeiptr(n) * 12, r.scratch_triangles.data());
    r.shadow_triangles.resize(mesh.triangle_count);
    std::copy(r.scratch_triangles.begin(), r.scratch_triangles.end(), r.shadow_triangles.begin() + tb);
    glNamedBufferSubData(r.outer_index_buffer, GLintptr(tb) * 12, GLsizeiptr(n) * 12, r.scratch_outer.data());
    glNamedBufferSubData(r.flag_buffer, GLintptr(tb), GLsizeiptr(n), r.scratch_flags.data());
    r.last_upload_bytes += uint64_t(n) * 25;
    upload_cut_faces(r, mesh);
  }

  r.vertex_count = mesh.vertex_count;
  r.triangle_count = mesh.triangle_count;
  // GPU normals: the adjacency follows the triangles (and a change of vertex count).
  if (gpu_normals && (tb < te || !r.gpu_normals || mesh.vertex_count != previous_vertex_count || r.adjacency_stale)) {
    rebuild_adjacency(r, mesh.triangles, mesh.triangle_count, mesh.vertex_count);
    r.adjacency_stale = false;
  }
  r.has_normals = has_normals;
  r.gpu_normals = gpu_normals;
  r.split_normals = split_normals;
  r.normals_stale = gpu_normals;
  r.uploaded = true;
}

void renderer_update_normals(Renderer& r) {
  if (r.gpu_normals && r.normals_stale && r.smooth_normal_program) compute_normals(r);
}

void renderer_draw(Renderer& r, const Camera& camera, const DrawOptions& options) {
  renderer_draw_surface(r, camera, options);
  if (has_target(r) && r.triangle_count > 0) tray_draw(r, camera, options);
}

void renderer_draw_surface(Renderer& r, const Camera& camera, const DrawOptions& options) {
  if (!has_target(r)) return;  // not initialised, or a failed resize
  r.presented = false;  // drawn into the offscreen target again
  const ViewTarget target = renderer_target(r);
  glBindFramebuffer(GL_FRAMEBUFFER, target.framebuffer);
  glViewport(target.x, target.y, target.width, target.height);
  const bool last_part = options.pieces_end >= std::clamp(options.surface_pieces, 1, 64);
  if (options.clear && options.pieces_begin <= 0) {
    // Direct: only the view's rectangle of the window.
    if (r.direct) {
      glEnable(GL_SCISSOR_TEST);
      glScissor(target.x, target.y, target.width, target.height);
    }
    glClearColor(options.background.x(), options.background.y(), options.background.z(), 1.0f);
    glClearDepth(1.0);
    glDepthMask(GL_TRUE);
    glClear(GL_COLOR_BUFFER_BIT | GL_DEPTH_BUFFER_BIT);
    glDisable(GL_SCISSOR_TEST);
  }
  if (r.triangle_count == 0 || !r.wire_program) return;

  // Camera and colours (the wire program uses only the view-projection and its colour).
  const Eigen::Matrix4f view = view_matrix(camera);
  const Eigen::Matrix4f view_projection = projection_matrix(camera, Viewport{r.width, r.height}.aspect()) * view;
  const Eigen::Matrix4f projection = projection_matrix(camera, Viewport{r.width, r.height}.aspect());
  const float unproject[4] = {2.0f / float(r.width), 2.0f / float(r.height), 1.0f / projection(0, 0), 1.0f / projection(1, 1)};
  // Each variant gets only the uniforms it uses (setting an inactive one is a GL error).
  for (int k = 0; k < 6; ++k) {
    const uint32_t program = r.surface_programs[k];
    const bool cut = (k & 1) != 0, flat = k == 2 || k == 3;
    glProgramUniformMatrix4fv(program, 0, 1, GL_FALSE, view_projection.data());
    glProgramUniformMatrix4fv(program, 1, 1, GL_FALSE, view.data());
    if (!cut) glProgramUniform3fv(program, 2, 1, options.surface_color.data());
    glProgramUniform3fv(program, 3, 1, options.cut_color.data());
    if (cut) glProgramUniform1i(program, 6, r.split_normals ? 1 : 0);
    if (flat) glProgramUniform4fv(program, 7, 1, unproject);
    if (flat) glProgramUniform2f(program, 8, projection(2, 2), projection(2, 3));
  }
  glProgramUniformMatrix4fv(r.wire_program, 0, 1, GL_FALSE, view_projection.data());
  renderer_update_normals(r);
  glBindFramebuffer(GL_FRAMEBUFFER, target.framebuffer);
  glProgramUniform3fv(r.wire_program, 5, 1, options.wire_color.data());

  // Both sides drawn and lit (no culling); normals only when the caller gave them.
  glEnable(GL_DEPTH_TEST);
  glDepthFunc(GL_LEQUAL);
  if (options.cull_back_faces) {
    glEnable(GL_CULL_FACE);
    glCullFace(GL_BACK);
    glFrontFace(GL_CCW);
  } else {
    glDisable(GL_CULL_FACE);
  }
  glDisable(GL_BLEND);
  if (r.samples > 0) glEnable(GL_MULTISAMPLE);
  if (r.has_normals || r.gpu_normals) {
    glEnableVertexArrayAttrib(r.vertex_array, 1);
  } else {
    glDisableVertexArrayAttrib(r.vertex_array, 1);
    glVertexAttrib3f(1, 0.0f, 0.0f, 0.0f);
  }
  if (r.split_normals) {
    glEnableVertexArrayAttrib(r.vertex_array, 2);
  } else {
    glDisableVertexArrayAttrib(r.vertex_array, 2);
    glVertexAttrib3f(2, 0.0f, 0.0f, 0.0f);
  }
  glBindVertexArray(r.vertex_array);
  glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 0, r.flag_buffer);
  const GLsizei index_count = GLsizei(std::min<uint64_t>(uint64_t(r.triangle_count) * 3, INT32_MAX / 3 * 3));
  // The index range is known (every slot names vertices below vertex_count: dead ones name 0), so
  // the draws pass it: with plain glDrawElements Mesa scans the whole index buffer for its bounds on
  // the CPU after every upload that touched it.
  const GLuint last_index = r.vertex_count > 0 ? r.vertex_count - 1 : 0;

  // Pass 1: the lit surface, the outer surface then the cut faces (each from its own index buffer,
  // the other class's slots degenerate there; the cut pass only over the slots that hold cut faces).
  glPolygonMode(GL_FRONT_AND_BACK, GL_FILL);
  // The program pair (outer, cut): smooth, flat (no normals) or smooth lit per vertex (kVertexShader:
  // only with back faces culled).
  const bool smooth = r.has_normals || r.gpu_normals;
  const int pair = !smooth ? 2 : options.vertex_lighting && options.cull_back_faces ? 4 : 0;
  glUseProgram(r.surface_programs[pair]);
  glVertexArrayElementBuffer(r.vertex_array, r.outer_index_buffer);
  // In pieces, each handed to the rasteriser at once (see DrawOptions::surface_pieces).
  const GLsizei pieces = GLsizei(std::clamp(options.surface_pieces, 1, 64));
  const GLsizei piece = (index_count / 3 + pieces - 1) / pieces * 3;
  const GLsizei piece_end = std::min<GLsizei>(std::max(options.pieces_end, 0), pieces);
  for (GLsizei k = std::max(options.pieces_begin, 0), first = k * piece; k < piece_end && first < index_count; ++k, first += piece) {
    glDrawRangeElements(GL_TRIANGLES, 0, last_index, std::min(piece, index_count - first), GL_UNSIGNED_INT,
                        reinterpret_cast<const void*>(uintptr_t(first) * 4));
    if (pieces > 1) glFlush();
  }
  if (r.cut_count > 0 && last_part) {
    glUseProgram(r.surface_programs[pair + 1]);
    glVertexArrayElementBuffer(r.vertex_array, r.cut_index_buffer);
    glDrawRangeElements(GL_TRIANGLES, 0, last_index, GLsizei(std::min<uint64_t>(r.cut_count, INT32_MAX / 3)) * 3,
                        GL_UNSIGNED_INT, nullptr);
  }
  glVertexArrayElementBuffer(r.vertex_array, r.index_buffer);  // every live slot (wireframe, compute)

  // Pass 2: edges on top, pulled toward the eye so they win the depth test against their own faces.
  if (options.wireframe && last_part) {
    glPolygonMode(GL_FRONT_AND_BACK, GL_LINE);
    glEnable(GL_POLYGON_OFFSET_LINE);
    glPolygonOffset(-1.0f, -1.0f);
    glUseProgram(r.wire_program);
    glDrawRangeElements(GL_TRIANGLES, 0, last_index, index_count, GL_UNSIGNED_INT, nullptr);
    glDisable(GL_POLYGON_OFFSET_LINE);
    glPolygonMode(GL_FRONT_AND_BACK, GL_FILL);
  }
  glUseProgram(0);
  glBindVertexArray(0);
  glDisable(GL_CULL_FACE);
}

bool renderer_read_pixels(Renderer& r, std::vector<uint8_t>& rgba) {
  if (!has_target(r)) return false;
  // Resolve the multisampled image first.
  if (r.resolve_framebuffer != r.framebuffer) {
    glBlitNamedFramebuffer(r.framebuffer, r.resolve_framebuffer, 0, 0, r.width, r.height, 0, 0, r.width, r.height,
                           GL_COLOR_BUFFER_BIT, GL_NEAREST);
  }
  const size_t row = size_t(r.width) * 4;
  rgba.resize(row * size_t(r.height));
  const ViewTarget target = renderer_target(r);
  const bool window = r.direct || r.presented;
  const GLuint read_framebuffer = window ? 0 : r.resolve_framebuffer;
  glBindFramebuffer(GL_READ_FRAMEBUFFER, read_framebuffer);
  glNamedFramebufferReadBuffer(read_framebuffer, window ? GL_BACK : GL_COLOR_ATTACHMENT0);
  glPixelStorei(GL_PACK_ALIGNMENT, 1);
  glReadPixels(target.x, target.y, r.width, r.height, GL_RGBA, GL_UNSIGNED_BYTE, rgba.data());
  glBindFramebuffer(GL_READ_FRAMEBUFFER, 0);
  // GL's row 0 is the bottom; images start at the top.
  std::vector<uint8_t> tmp(row);
  for (int y = 0; y < r.height / 2; ++y) {
    uint8_t* a = rgba.data() + size_t(y) * row;
    uint8_t* b = rgba.data() + size_t(r.height - 1 - y) * row;
    std::memcpy(tmp.data(), a, row);
    std::memcpy(a, b, row);
    std::memcpy(b, tmp.data(), row);
  }
  std::string error;
  return gl_check_errors(error);
}

void renderer_blit(Renderer& r, uint32_t target_framebuffer, int width, int height, int x, int y) {
  if (!r.framebuffer || r.direct) return;
  // A multisampled image resolves at its own size first (a resolving blit cannot scale).
  GLuint source = r.framebuffer;
  if (r.resolve_framebuffer != r.framebuffer) {
    glBlitNamedFramebuffer(r.framebuffer, r.resolve_framebuffer, 0, 0, r.width, r.height, 0, 0, r.width, r.height,
                           GL_COLOR_BUFFER_BIT, GL_NEAREST);
    source = r.resolve_framebuffer;
  }
  glBlitNamedFramebuffer(source, target_framebuffer, 0, 0, r.width, r.height, x, y, x + width, y + height,
                         GL_COLOR_BUFFER_BIT, (width == r.width && height == r.height) ? GL_NEAREST : GL_LINEAR);
}

bool renderer_double_buffer(Renderer& r, std::string& error) {
  if (r.direct || r.samples > 0) return false;
  r.double_buffered = true;
  return renderer_resize(r, r.width, r.height, error);
}

void renderer_show_drawn(Renderer& r) {
  if (!r.shown_framebuffer) return;
  std::swap(r.framebuffer, r.shown_framebuffer);
  std::swap(r.color_renderbuffer, r.shown_color_renderbuffer);
  std::swap(r.depth_texture, r.shown_depth_texture);
  r.resolve_framebuffer = r.framebuffer;
}

void renderer_present(Renderer& r) {
  if (!r.framebuffer || r.direct || r.samples > 0) return;
  glBlitNamedFramebuffer(r.shown_framebuffer ? r.shown_framebuffer : r.framebuffer, 0, 0, 0, r.width, r.height, r.origin_x, r.origin_y, r.origin_x + r.width,
                         r.origin_y + r.height, GL_COLOR_BUFFER_BIT, GL_NEAREST);
  r.presented = true;
}

void renderer_destroy(Renderer& r) {
  destroy_target(r);
  for (uint32_t program : r.surface_programs)
    if (program) glDeleteProgram(program);
  if (r.wire_program) glDeleteProgram(r.wire_program);
  if (r.triangle_normal_program) glDeleteProgram(r.triangle_normal_program);
  if (r.vertex_normal_program) glDeleteProgram(r.vertex_normal_program);
  if (r.smooth_normal_program) glDeleteProgram(r.smooth_normal_program);
  tray_destroy(r);
  if (r.vertex_array) glDeleteVertexArrays(1, &r.vertex_array);
  const GLuint buffers[] = {r.position_buffer,   r.normal_buffer,         r.index_buffer,
                            r.outer_index_buffer, r.cut_index_buffer,
                            r.flag_buffer,       r.cut_normal_buffer,     r.corner_normal_buffer,
                            r.adjacency_offset_buffer, r.adjacency_buffer};
  for (GLuint b : buffers)
    if (b) glDeleteBuffers(1, &b);
  r = Renderer{};
}

bool gl_check_errors(std::string& error) {
  error.clear();
  for (int i = 0; i < 16; ++i) {  // bounded: a lost context can report errors forever
    const GLenum e = glGetError();
    if (e == GL_NO_ERROR) break;
    const char* name = e == GL_INVALID_ENUM        ? "GL_INVALID_ENUM"
                       : e == GL_INVALID_VALUE     ? "GL_INVALID_VALUE"
                       : e == GL_INVALID_OPERATION ? "GL_INVALID_OPERATION"
                       : e == GL_OUT_OF_MEMORY     ? "GL_OUT_OF_MEMORY"
                       : e == GL_INVALID_FRAMEBUFFER_OPERATION ? "GL_INVALID_FRAMEBUFFER_OPERATION"
                                                               : "GL error";
    if (!error.empty()) error += ", ";
    error += name;
  }
  return error.empty();
}

}  // namespace dvx
