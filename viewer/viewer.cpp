#include "viewer/viewer.h"

#define GL_GLEXT_PROTOTYPES 1
#include <EGL/egl.h>
#include <EGL/eglext.h>
#include <GL/gl.h>
#include <GL/glext.h>
#include <GLFW/glfw3.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <opencv2/imgproc.hpp>
#include <stdexcept>

namespace d3d {

void ViewerOptions::Check() const {
  if (width < 64 || height < 64 || width > 8192 || height > 8192)
    throw std::invalid_argument("ViewerOptions: size out of 64..8192 px");
  if (!(point_size_px > 0)) throw std::invalid_argument("ViewerOptions: point_size_px must be > 0");
}

namespace {

cv::Scalar CueColourBgr(PreviewCue c) {
  switch (c) {
    case PreviewCue::kTracking:
      return {60, 190, 60};
    case PreviewCue::kLost:
      return {40, 40, 220};
    case PreviewCue::kRelocalised:
      return {0, 200, 230};
    case PreviewCue::kProbeLost:
      return {200, 40, 200};
    case PreviewCue::kPaused:
      return {200, 120, 40};
    case PreviewCue::kNewSegment:
      return {230, 160, 0};  // blue: scanning on, apart from the model
    case PreviewCue::kSlowDown:
      return {0, 200, 255};  // amber: tracking, the host falls behind the hand
    case PreviewCue::kLostSlowDown:
      return {40, 40, 220};  // as lost: the host fell so far behind that the track failed
    case PreviewCue::kWaiting:
      return {128, 128, 128};
  }
  return {255, 255, 255};
}

// FBO entry points (GL 3.0), looked up at run time: the EGL path renders into one.
struct FboFns {
  PFNGLGENFRAMEBUFFERSPROC GenFramebuffers = nullptr;
  PFNGLBINDFRAMEBUFFERPROC BindFramebuffer = nullptr;
  PFNGLGENRENDERBUFFERSPROC GenRenderbuffers = nullptr;
  PFNGLBINDRENDERBUFFERPROC BindRenderbuffer = nullptr;
  PFNGLRENDERBUFFERSTORAGEPROC RenderbufferStorage = nullptr;
  PFNGLFRAMEBUFFERRENDERBUFFERPROC FramebufferRenderbuffer = nullptr;
  PFNGLCHECKFRAMEBUFFERSTATUSPROC CheckFramebufferStatus = nullptr;
  bool Load() {
    GenFramebuffers =
        reinterpret_cast<PFNGLGENFRAMEBUFFERSPROC>(eglGetProcAddress("glGenFramebuffers"));
    BindFramebuffer =
        reinterpret_cast<PFNGLBINDFRAMEBUFFERPROC>(eglGetProcAddress("glBindFramebuffer"));
    GenRenderbuffers =
        reinterpret_cast<PFNGLGENRENDERBUFFERSPROC>(eglGetProcAddress("glGenRenderbuffers"));
    BindRenderbuffer =
        reinterpret_cast<PFNGLBINDRENDERBUFFERPROC>(eglGetProcAddress("glBindRenderbuffer"));
    RenderbufferStorage =
        reinterpret_cast<PFNGLRENDERBUFFERSTORAGEPROC>(eglGetProcAddress("glRenderbufferStorage"));
    FramebufferRenderbuffer = reinterpret_cast<PFNGLFRAMEBUFFERRENDERBUFFERPROC>(
        eglGetProcAddress("glFramebufferRenderbuffer"));
    CheckFramebufferStatus = reinterpret_cast<PFNGLCHECKFRAMEBUFFERSTATUSPROC>(
        eglGetProcAddress("glCheckFramebufferStatus"));
    return GenFramebuffers && BindFramebuffer && GenRenderbuffers && BindRenderbuffer &&
           RenderbufferStorage && FramebufferRenderbuffer && CheckFramebufferStatus;
  }
};

}  // namespace

// Status panel: the rows it takes at the top of the frame (cue box and four lines of text), and
// the keys line's strip at the bottom of a window.
constexpr int kHudPanelRows = 150, kHudKeysRows = 28;

struct Viewer::Impl {
  ViewerOptions o;
  // Window path.
  GLFWwindow* window = nullptr;
  // Offscreen path.
  EGLDisplay egl_display = EGL_NO_DISPLAY;
  EGLContext egl_context = EGL_NO_CONTEXT;
  GLuint fbo = 0, colour_rb = 0, depth_rb = 0;
  int width = 0, height = 0;
  // Orbit camera (model frame: the first view's camera, x right, y down, z forward).
  float yaw = 0, pitch = 0, distance_mm = 60;
  Eigen::Vector3f target = Eigen::Vector3f::Zero();
  bool auto_fit = true;
  bool dragging = false;
  double last_x = 0, last_y = 0;
  std::vector<ViewerAction> actions;
  // Render buffers (reused).
  std::vector<uint8_t> colours, segment_colours;
  cv::Mat hud;  // BGRA
  PanelRefresh hud_refresh;
  GLuint hud_tex = 0;
  bool hud_dirty = true;
  // What the last drawn frame showed. A frame whose picture would be the same (no new view, same
  // camera and panel) is not drawn again: on a software renderer the preview cost a quarter of a
  // core at 20 fps, which a host that cannot keep up needs for the scan (docs/decisions/0014).
  struct SceneKey {
    uint64_t generation = 0, segment_generation = 0, last_burst_seq = 0;
    size_t points = 0, segment_points = 0, view_points = 0;
    bool snapshot = false, have_pose = false, view_accepted = false;
    PreviewCue cue = PreviewCue::kWaiting;
    float yaw = 0, pitch = 0, distance_mm = 0;
    Eigen::Vector3f target = Eigen::Vector3f::Zero();
    int width = 0, height = 0;
    bool operator==(const SceneKey&) const = default;
  };
  SceneKey drawn_key;    // valid once frames_drawn > 0
  bool exposed = false;  // the window asked for its content again (uncovered, resized)
  int64_t frames_drawn = 0;

  ~Impl() {
    if (hud_tex != 0) glDeleteTextures(1, &hud_tex);
    if (window != nullptr) {
      glfwDestroyWindow(window);
      glfwTerminate();
    }
    if (egl_display != EGL_NO_DISPLAY) {
      eglMakeCurrent(egl_display, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT);
      if (egl_context != EGL_NO_CONTEXT) eglDestroyContext(egl_display, egl_context);
      eglTerminate(egl_display);
    }
  }

  Status CreateWindow() {
    if (!glfwInit())
      return Status(StatusCode::kUnavailable,
                    "GLFW cannot start (no display? run under xvfb-run -a, or use --headless)");
    glfwWindowHint(GLFW_SAMPLES, 0);
    window = glfwCreateWindow(o.width, o.height, o.title.c_str(), nullptr, nullptr);
    if (window == nullptr) {
      glfwTerminate();
      return Status(StatusCode::kUnavailable, "GLFW cannot open an OpenGL window");
    }
    glfwMakeContextCurrent(window);
    glfwSwapInterval(0);
    glfwSetWindowUserPointer(window, this);
    glfwSetKeyCallback(window, [](GLFWwindow* w, int key, int, int action, int) {
      auto* self = static_cast<Impl*>(glfwGetWindowUserPointer(w));
      if (action != GLFW_PRESS) return;
      if (key == GLFW_KEY_SPACE)
        self->actions.push_back(ViewerAction::kPause);
      else if (key == GLFW_KEY_R)
        self->actions.push_back(ViewerAction::kReset);
      else if (key == GLFW_KEY_U)
        self->actions.push_back(ViewerAction::kUndo);
      else if (key == GLFW_KEY_S)
        self->actions.push_back(ViewerAction::kSave);
      else if (key == GLFW_KEY_Q || key == GLFW_KEY_ESCAPE)
        self->actions.push_back(ViewerAction::kQuit);
      else if (key == GLFW_KEY_F)
        self->auto_fit = true;
    });
    glfwSetMouseButtonCallback(window, [](GLFWwindow* w, int button, int action, int) {
      auto* self = static_cast<Impl*>(glfwGetWindowUserPointer(w));
      if (button == GLFW_MOUSE_BUTTON_LEFT) {
        self->dragging = action == GLFW_PRESS;
        glfwGetCursorPos(w, &self->last_x, &self->last_y);
      }
    });
    glfwSetCursorPosCallback(window, [](GLFWwindow* w, double x, double y) {
      auto* self = static_cast<Impl*>(glfwGetWindowUserPointer(w));
      if (!self->dragging) return;
      self->yaw += static_cast<float>(x - self->last_x) * 0.008f;
      self->pitch =
          std::clamp(self->pitch + static_cast<float>(y - self->last_y) * 0.008f, -1.5f, 1.5f);
      self->last_x = x;
      self->last_y = y;
      self->auto_fit = false;
    });
    glfwSetWindowRefreshCallback(window, [](GLFWwindow* w) {
      static_cast<Impl*>(glfwGetWindowUserPointer(w))->exposed = true;
    });
    glfwSetScrollCallback(window, [](GLFWwindow* w, double, double dy) {
      auto* self = static_cast<Impl*>(glfwGetWindowUserPointer(w));
      self->distance_mm =
          std::clamp(self->distance_mm * static_cast<float>(std::pow(0.9, dy)), 2.0f, 2000.0f);
      self->auto_fit = false;
    });
    return Status::Ok();
  }

  Status CreateOffscreen() {
    auto get_platform_display = reinterpret_cast<PFNEGLGETPLATFORMDISPLAYEXTPROC>(
        eglGetProcAddress("eglGetPlatformDisplayEXT"));
    if (get_platform_display == nullptr)
      return Status(StatusCode::kUnavailable, "EGL: no eglGetPlatformDisplayEXT");
    egl_display = get_platform_display(EGL_PLATFORM_SURFACELESS_MESA, EGL_DEFAULT_DISPLAY, nullptr);
    EGLint major = 0, minor = 0;
    if (egl_display == EGL_NO_DISPLAY || !eglInitialize(egl_display, &major, &minor)) {
      egl_display = EGL_NO_DISPLAY;
      return Status(StatusCode::kUnavailable, "EGL: Mesa's surfaceless platform is not available");
    }
    const EGLint attribs[] = {EGL_SURFACE_TYPE,
                              0,
                              EGL_RENDERABLE_TYPE,
                              EGL_OPENGL_BIT,
                              EGL_RED_SIZE,
                              8,
                              EGL_GREEN_SIZE,
                              8,
                              EGL_BLUE_SIZE,
                              8,
                              EGL_NONE};
    EGLConfig config = nullptr;
    EGLint n = 0;
    if (!eglChooseConfig(egl_display, attribs, &config, 1, &n) || n < 1)
      return Status(StatusCode::kUnavailable, "EGL: no OpenGL config");
    if (!eglBindAPI(EGL_OPENGL_API))
      return Status(StatusCode::kUnavailable, "EGL: no desktop OpenGL");
    egl_context = eglCreateContext(egl_display, config, EGL_NO_CONTEXT, nullptr);
    if (egl_context == EGL_NO_CONTEXT)
      return Status(StatusCode::kUnavailable, "EGL: cannot create an OpenGL context");
    if (!eglMakeCurrent(egl_display, EGL_NO_SURFACE, EGL_NO_SURFACE, egl_context))
      return Status(StatusCode::kUnavailable, "EGL: surfaceless context cannot be made current");
    FboFns f;
    if (!f.Load()) return Status(StatusCode::kUnavailable, "OpenGL: no framebuffer objects");
    f.GenFramebuffers(1, &fbo);
    f.BindFramebuffer(GL_FRAMEBUFFER, fbo);
    f.GenRenderbuffers(1, &colour_rb);
    f.BindRenderbuffer(GL_RENDERBUFFER, colour_rb);
    f.RenderbufferStorage(GL_RENDERBUFFER, GL_RGBA8, o.width, o.height);
    f.FramebufferRenderbuffer(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_RENDERBUFFER, colour_rb);
    f.GenRenderbuffers(1, &depth_rb);
    f.BindRenderbuffer(GL_RENDERBUFFER, depth_rb);
    f.RenderbufferStorage(GL_RENDERBUFFER, GL_DEPTH_COMPONENT24, o.width, o.height);
    f.FramebufferRenderbuffer(GL_FRAMEBUFFER, GL_DEPTH_ATTACHMENT, GL_RENDERBUFFER, depth_rb);
    if (f.CheckFramebufferStatus(GL_FRAMEBUFFER) != GL_FRAMEBUFFER_COMPLETE)
      return Status(StatusCode::kUnavailable, "OpenGL: framebuffer incomplete");
    width = o.width;
    height = o.height;
    return Status::Ok();
  }

  void Fit(const PreviewSnapshot& s) {
    if (s.points.empty() && s.segment_points.empty()) {
      if (s.have_pose) {
        target =
            (s.model_from_cam * Eigen::Vector4f(0, 0, 0.5f * (s.near_mm + s.far_mm), 1)).head<3>();
        distance_mm = 60;
      }
      return;
    }
    Eigen::Vector3f lo = s.points.empty() ? s.segment_points.front() : s.points.front(), hi = lo;
    for (const auto* cloud : {&s.points, &s.segment_points})
      for (const auto& p : *cloud) {
        lo = lo.cwiseMin(p);
        hi = hi.cwiseMax(p);
      }
    target = 0.5f * (lo + hi);
    const float radius = std::max(0.5f * (hi - lo).norm(), 5.0f);
    distance_mm = radius / std::tan(0.5f * 40.0f * static_cast<float>(M_PI) / 180.0f) * 1.05f;
  }

  // model_from_eye of the orbit camera (eye looks along +z, y down: the model's camera convention).
  Eigen::Matrix4f ModelFromEye() const {
    const Eigen::Matrix3f r = (Eigen::AngleAxisf(yaw, Eigen::Vector3f::UnitY()) *
                               Eigen::AngleAxisf(-pitch, Eigen::Vector3f::UnitX()))
                                  .toRotationMatrix();
    Eigen::Matrix4f m = Eigen::Matrix4f::Identity();
    m.topLeftCorner<3, 3>() = r;
    m.topRightCorner<3, 1>() = target - r * Eigen::Vector3f(0, 0, distance_mm);
    return m;
  }

  // The cue shown: the host's override (probe lost, paused, waiting) or the snapshot's.
  static PreviewCue ShownCue(const PreviewSnapshot* s, const PreviewStatus& st) {
    return st.override_cue ? st.cue_override : (s ? s->cue : PreviewCue::kWaiting);
  }

  SceneKey KeyOf(const PreviewSnapshot* s, const PreviewStatus& st) const {
    SceneKey k;
    if (s != nullptr) {
      k.snapshot = true;
      k.generation = s->generation;
      k.segment_generation = s->segment_generation;
      k.last_burst_seq = s->last_burst_seq;
      k.points = s->points.size();
      k.segment_points = s->segment_points.size();
      k.view_points = s->view_points.size();
      k.have_pose = s->have_pose;
      k.view_accepted = s->view_accepted;
    }
    k.cue = ShownCue(s, st);
    k.yaw = yaw;
    k.pitch = pitch;
    k.distance_mm = distance_mm;
    k.target = target;
    k.width = width;
    k.height = height;
    return k;
  }

  // Draws the panel's texture again when PanelRefresh says so; true when it did.
  bool UpdateHud(const PreviewSnapshot* s, const PreviewStatus& st, double fps) {
    const PreviewCue cue = ShownCue(s, st);
    char l1[160], l2[160], l3[160];
    std::snprintf(l1, sizeof l1,
                  "bursts %llu received  %llu processed  %llu fused  %llu dropped  %llu refused",
                  static_cast<unsigned long long>(st.bursts_received),
                  static_cast<unsigned long long>(st.bursts_processed),
                  static_cast<unsigned long long>(st.bursts_fused),
                  static_cast<unsigned long long>(st.bursts_dropped),
                  static_cast<unsigned long long>(st.bursts_rejected));
    std::snprintf(l2, sizeof l2,
                  "%.1f bursts/s   latency p50 %.0f ms  p95 %.0f ms   preview %.0f fps",
                  st.bursts_per_s, st.latency_ms_p50, st.latency_ms_p95, fps);
    std::snprintf(l3, sizeof l3, "coverage %.0f mm2   %zu points", s ? s->model_area_mm2 : 0.0,
                  s ? s->points.size() : size_t{0});
    std::string text = PreviewCueText(cue);
    for (const char* l : {l1, l2, l3}) text.append("\n").append(l);
    text.append("\n").append(st.message);
    const int64_t now_ns = std::chrono::duration_cast<std::chrono::nanoseconds>(
                               std::chrono::steady_clock::now().time_since_epoch())
                               .count();
    if (!hud_refresh.Due(cue, st.message, text, now_ns, hud_dirty)) return false;
    hud_dirty = false;
    // The texture holds the panel's rows (kHudPanelRows) and, in a window, the keys line below
    // them (kHudKeysRows): only those strips are drawn, not a quad over the whole frame
    // (llvmpipe blends every pixel of a quad, and the texture is uploaded whenever the text
    // changes).
    const int keys_rows = headless_mode() ? 0 : kHudKeysRows;
    hud.create(kHudPanelRows + keys_rows, width, CV_8UC4);
    hud.setTo(cv::Scalar(0, 0, 0, 0));
    const cv::Scalar colour = CueColourBgr(cue);
    cv::rectangle(hud, cv::Rect(10, 10, 250, 34), cv::Scalar(colour[0], colour[1], colour[2], 255),
                  cv::FILLED);
    cv::putText(hud, PreviewCueText(cue), {18, 34}, cv::FONT_HERSHEY_SIMPLEX, 0.65,
                cv::Scalar(255, 255, 255, 255), 2, cv::LINE_AA);
    int y = 66;
    for (const char* l : {static_cast<const char*>(l1), static_cast<const char*>(l2),
                          static_cast<const char*>(l3), st.message.c_str()}) {
      cv::putText(hud, l, {12, y}, cv::FONT_HERSHEY_SIMPLEX, 0.5, cv::Scalar(0, 0, 0, 255), 3,
                  cv::LINE_AA);
      cv::putText(hud, l, {12, y}, cv::FONT_HERSHEY_SIMPLEX, 0.5, cv::Scalar(255, 255, 255, 255), 1,
                  cv::LINE_AA);
      y += 22;
    }
    if (keys_rows > 0) {
      const char* keys =
          "drag: orbit   wheel: zoom   f: fit   space: pause   r: reset   u: undo   s: save   q: "
          "quit";
      cv::putText(hud, keys, {12, kHudPanelRows + keys_rows - 10}, cv::FONT_HERSHEY_SIMPLEX, 0.45,
                  cv::Scalar(200, 200, 200, 255), 1, cv::LINE_AA);
    }
    if (hud_tex == 0) glGenTextures(1, &hud_tex);
    glBindTexture(GL_TEXTURE_2D, hud_tex);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_NEAREST);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_NEAREST);
    glPixelStorei(GL_UNPACK_ALIGNMENT, 4);
    glTexImage2D(GL_TEXTURE_2D, 0, GL_RGBA8, hud.cols, hud.rows, 0, GL_BGRA, GL_UNSIGNED_BYTE,
                 hud.data);
    return true;
  }
  bool headless_mode() const { return window == nullptr; }

  // The frame (the panel's texture as UpdateHud left it).
  void Draw(const PreviewSnapshot* s, const PreviewStatus& st) {
    glViewport(0, 0, width, height);
    glClearColor(0.12f, 0.13f, 0.16f, 1.0f);
    glClear(GL_COLOR_BUFFER_BIT | GL_DEPTH_BUFFER_BIT);
    // Projection: 40° vertical field.
    const double aspect = static_cast<double>(width) / height;
    const double near_mm = std::max(0.5, distance_mm * 0.05), far_mm = distance_mm * 20 + 200;
    const double top = near_mm * std::tan(20.0 * M_PI / 180.0);
    glMatrixMode(GL_PROJECTION);
    glLoadIdentity();
    glFrustum(-top * aspect, top * aspect, -top, top, near_mm, far_mm);
    // GL eye (x right, y up, looking along −z) from the orbit eye (x right, y down, along +z).
    Eigen::Matrix4f gl_from_eye = Eigen::Matrix4f::Identity();
    gl_from_eye(1, 1) = -1;
    gl_from_eye(2, 2) = -1;
    const Eigen::Matrix4f model_from_eye = ModelFromEye();
    const Eigen::Matrix4f gl_from_model = gl_from_eye * model_from_eye.inverse();
    glMatrixMode(GL_MODELVIEW);
    glLoadMatrixf(gl_from_model.data());  // column major, as GL wants
    glEnable(GL_DEPTH_TEST);
    if (s != nullptr) {
      // Model points, shaded by a headlight: |n · view direction|.
      const Eigen::Vector3f dir = model_from_eye.block<3, 1>(0, 2);
      // RGB shaded by floor + (1 − floor) · |n · dir|.
      const auto shade = [&](const std::vector<Eigen::Vector3f>& normals, const float rgb[3],
                             float floor, std::vector<uint8_t>* out) {
        out->resize(normals.size() * 3);
        for (size_t i = 0; i < normals.size(); ++i) {
          const float f = floor + (1 - floor) * std::abs(normals[i].dot(dir));
          for (size_t k = 0; k < 3; ++k) (*out)[3 * i + k] = static_cast<uint8_t>(rgb[k] * f);
        }
      };
      const float ivory[3] = {235, 228, 205};
      shade(s->normals, ivory, 0.25f, &colours);
      glPointSize(o.point_size_px);
      glEnableClientState(GL_VERTEX_ARRAY);
      glEnableClientState(GL_COLOR_ARRAY);
      if (!s->points.empty()) {
        glVertexPointer(3, GL_FLOAT, sizeof(Eigen::Vector3f), s->points.data());
        glColorPointer(3, GL_UNSIGNED_BYTE, 0, colours.data());
        glDrawArrays(GL_POINTS, 0, static_cast<GLsizei>(s->points.size()));
      }
      // The segment apart from the model, in the NEW SEGMENT colour, shaded alike.
      if (!s->segment_points.empty()) {
        const cv::Scalar c = CueColourBgr(PreviewCue::kNewSegment);
        const float blue[3] = {static_cast<float>(c[2]), static_cast<float>(c[1]),
                               static_cast<float>(c[0])};
        shade(s->segment_normals, blue, 0.35f, &segment_colours);
        glVertexPointer(3, GL_FLOAT, sizeof(Eigen::Vector3f), s->segment_points.data());
        glColorPointer(3, GL_UNSIGNED_BYTE, 0, segment_colours.data());
        glDrawArrays(GL_POINTS, 0, static_cast<GLsizei>(s->segment_points.size()));
      }
      glDisableClientState(GL_COLOR_ARRAY);
      // The current view, highlighted.
      if (!s->view_points.empty()) {
        if (s->view_accepted)
          glColor3ub(255, 150, 30);
        else
          glColor3ub(230, 40, 40);
        glPointSize(o.point_size_px + 1);
        glVertexPointer(3, GL_FLOAT, sizeof(Eigen::Vector3f), s->view_points.data());
        glDrawArrays(GL_POINTS, 0, static_cast<GLsizei>(s->view_points.size()));
      }
      glDisableClientState(GL_VERTEX_ARRAY);
      // The probe frustum (apex = camera centre, near and far rectangles of the measurement
      // volume).
      if (s->have_pose) {
        const PreviewCue cue = ShownCue(s, st);
        const cv::Scalar c = CueColourBgr(cue);
        glColor3ub(static_cast<GLubyte>(c[2]), static_cast<GLubyte>(c[1]),
                   static_cast<GLubyte>(c[0]));
        glLineWidth(2);
        auto corner = [&](float z, int sx, int sy) {
          const Eigen::Vector4f p(sx * s->tan_half_x * z, sy * s->tan_half_y * z, z, 1);
          const Eigen::Vector3f w = (s->model_from_cam * p).head<3>();
          glVertex3f(w.x(), w.y(), w.z());
        };
        const Eigen::Vector3f apex = s->model_from_cam.topRightCorner<3, 1>();
        glBegin(GL_LINES);
        for (int sx : {-1, 1})
          for (int sy : {-1, 1}) {
            glVertex3f(apex.x(), apex.y(), apex.z());
            corner(s->far_mm, sx, sy);
          }
        glEnd();
        for (float z : {s->near_mm, s->far_mm}) {
          glBegin(GL_LINE_LOOP);
          corner(z, -1, -1);
          corner(z, 1, -1);
          corner(z, 1, 1);
          corner(z, -1, 1);
          glEnd();
        }
      }
    }
    // Status panel.
    glDisable(GL_DEPTH_TEST);
    glMatrixMode(GL_PROJECTION);
    glLoadIdentity();
    glOrtho(0, width, height, 0, -1, 1);
    glMatrixMode(GL_MODELVIEW);
    glLoadIdentity();
    glEnable(GL_TEXTURE_2D);
    glEnable(GL_BLEND);
    glBlendFunc(GL_SRC_ALPHA, GL_ONE_MINUS_SRC_ALPHA);
    glBindTexture(GL_TEXTURE_2D, hud_tex);
    glColor4f(1, 1, 1, 1);
    // Texture rows [r0, r1) onto frame rows [y0, y0 + r1 − r0).
    const auto strip = [&](int r0, int r1, int y0) {
      const float t0 = static_cast<float>(r0) / static_cast<float>(hud.rows),
                  t1 = static_cast<float>(r1) / static_cast<float>(hud.rows);
      const float w = static_cast<float>(width), ya = static_cast<float>(y0),
                  yb = static_cast<float>(y0 + r1 - r0);
      glTexCoord2f(0, t0);
      glVertex2f(0, ya);
      glTexCoord2f(1, t0);
      glVertex2f(w, ya);
      glTexCoord2f(1, t1);
      glVertex2f(w, yb);
      glTexCoord2f(0, t1);
      glVertex2f(0, yb);
    };
    glBegin(GL_QUADS);
    strip(0, kHudPanelRows, 0);
    if (hud.rows > kHudPanelRows)
      strip(kHudPanelRows, hud.rows, height - (hud.rows - kHudPanelRows));
    glEnd();
    glDisable(GL_BLEND);
    glDisable(GL_TEXTURE_2D);
  }
};

Viewer::Viewer(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
Viewer::~Viewer() = default;

Status Viewer::Create(const ViewerOptions& options, std::unique_ptr<Viewer>* out) {
  options.Check();
  auto impl = std::make_unique<Impl>();
  impl->o = options;
  D3D_RETURN_IF_ERROR(options.headless ? impl->CreateOffscreen() : impl->CreateWindow());
  if (impl->window != nullptr) glfwGetFramebufferSize(impl->window, &impl->width, &impl->height);
  out->reset(new Viewer(std::move(impl)));
  return Status::Ok();
}

bool Viewer::headless() const { return impl_->window == nullptr; }

bool Viewer::Render(const PreviewSnapshot* snapshot, const PreviewStatus& status, double fps,
                    cv::Mat* capture) {
  Impl& m = *impl_;
  if (m.window != nullptr) {
    glfwPollEvents();
    if (glfwWindowShouldClose(m.window)) return false;
    int w = 0, h = 0;
    glfwGetFramebufferSize(m.window, &w, &h);
    if (w != m.width || h != m.height) m.hud_dirty = true;
    m.width = std::max(w, 1);
    m.height = std::max(h, 1);
  }
  if (capture != nullptr) m.hud_dirty = true;  // a saved picture shows the current counters
  if (snapshot != nullptr && m.auto_fit) m.Fit(*snapshot);
  const bool hud_changed = m.UpdateHud(snapshot, status, fps);
  const Impl::SceneKey key = m.KeyOf(snapshot, status);
  if (!hud_changed && capture == nullptr && !m.exposed && m.frames_drawn > 0 && key == m.drawn_key)
    return true;  // still current
  m.Draw(snapshot, status);
  m.drawn_key = key;
  m.exposed = false;
  ++m.frames_drawn;
  glFinish();
  if (capture != nullptr) {
    cv::Mat bgra(m.height, m.width, CV_8UC4);
    glPixelStorei(GL_PACK_ALIGNMENT, 4);
    glReadBuffer(m.window != nullptr ? GL_BACK : GL_COLOR_ATTACHMENT0);
    glReadPixels(0, 0, m.width, m.height, GL_BGRA, GL_UNSIGNED_BYTE, bgra.data);
    cv::cvtColor(bgra, *capture, cv::COLOR_BGRA2BGR);
    cv::flip(*capture, *capture, 0);
  }
  if (m.window != nullptr) glfwSwapBuffers(m.window);
  return true;
}

int64_t Viewer::frames_drawn() const { return impl_->frames_drawn; }

std::vector<ViewerAction> Viewer::TakeActions() {
  std::vector<ViewerAction> a;
  a.swap(impl_->actions);
  return a;
}

}  // namespace d3d
