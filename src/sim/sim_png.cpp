// Top-down PNG of a simulated scene, rasterised here (libpng only writes the pixels).
#include <png.h>

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "dtif/io/dataset.h"
#include "dtif/sim/sim_world.h"
#include "dtif/sim/simulator.h"

namespace dtif::sim {
namespace {

struct Rgb {
  uint8_t r, g, b;
};

// Robot colours (distinct on a light background).
const Rgb kRobotColours[] = {{220, 40, 40},  {30, 100, 220}, {230, 140, 0},
                             {150, 40, 200}, {0, 160, 160},  {200, 0, 120}};

class Canvas {
 public:
  Canvas(int w, int h) : w_(w), h_(h), px_(static_cast<size_t>(w) * h * 3, 255) {}
  int width() const { return w_; }
  int height() const { return h_; }
  void set(int x, int y, Rgb c, double alpha = 1.0) {
    if (x < 0 || y < 0 || x >= w_ || y >= h_) return;
    uint8_t* p = &px_[(static_cast<size_t>(y) * w_ + x) * 3];
    p[0] = static_cast<uint8_t>(p[0] * (1 - alpha) + c.r * alpha);
    p[1] = static_cast<uint8_t>(p[1] * (1 - alpha) + c.g * alpha);
    p[2] = static_cast<uint8_t>(p[2] * (1 - alpha) + c.b * alpha);
  }
  void disk(double cx, double cy, double r, Rgb c, double alpha = 1.0) {
    const int x0 = static_cast<int>(std::floor(cx - r)), x1 = static_cast<int>(std::ceil(cx + r));
    const int y0 = static_cast<int>(std::floor(cy - r)), y1 = static_cast<int>(std::ceil(cy + r));
    for (int y = y0; y <= y1; ++y) {
      for (int x = x0; x <= x1; ++x) {
        if ((x + 0.5 - cx) * (x + 0.5 - cx) + (y + 0.5 - cy) * (y + 0.5 - cy) <= r * r) {
          set(x, y, c, alpha);
        }
      }
    }
  }
  void line(double x0, double y0, double x1, double y1, Rgb c, double width = 1.0,
            double alpha = 1.0) {
    const double len = std::hypot(x1 - x0, y1 - y0);
    const int n = std::max(1, static_cast<int>(len * 2));
    for (int i = 0; i <= n; ++i) {
      const double t = static_cast<double>(i) / n;
      if (width <= 1.0) {
        set(static_cast<int>(x0 + t * (x1 - x0)), static_cast<int>(y0 + t * (y1 - y0)), c, alpha);
      } else {
        disk(x0 + t * (x1 - x0), y0 + t * (y1 - y0), 0.5 * width, c, alpha);
      }
    }
  }
  void save(const std::string& path) const {
    FILE* f = std::fopen(path.c_str(), "wb");
    if (!f) throw DatasetError(path + ": cannot write the PNG");
    png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, nullptr, nullptr, nullptr);
    png_infop info = png ? png_create_info_struct(png) : nullptr;
    if (!png || !info || setjmp(png_jmpbuf(png))) {
      png_destroy_write_struct(&png, &info);
      std::fclose(f);
      throw DatasetError(path + ": PNG encoding failed");
    }
    png_init_io(png, f);
    png_set_IHDR(png, info, w_, h_, 8, PNG_COLOR_TYPE_RGB, PNG_INTERLACE_NONE,
                 PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
    png_write_info(png, info);
    for (int y = 0; y < h_; ++y) {
      png_write_row(png, const_cast<png_bytep>(&px_[static_cast<size_t>(y) * w_ * 3]));
    }
    png_write_end(png, nullptr);
    png_destroy_write_struct(&png, &info);
    if (std::fclose(f) != 0) throw DatasetError(path + ": cannot write the PNG");
  }

 private:
  int w_, h_;
  std::vector<uint8_t> px_;
};

// Plot coordinates (W, metres) to pixels. Image y grows downwards; W's y grows upwards.
struct View {
  Eigen::Vector2d lo, hi;  // extent shown [m]
  double px_per_m;
  double X(double x) const { return (x - lo.x()) * px_per_m; }
  double Y(double y) const { return (hi.y() - y) * px_per_m; }
};

// Terrain: light shading by height with 1 m contour lines.
void drawTerrain(const World& world, const View& v, Canvas* canvas) {
  Canvas& c = *canvas;
  const Eigen::Vector2d& lo = v.lo;
  const Eigen::Vector2d& hi = v.hi;
  const double px_per_m = v.px_per_m;
  const int w = c.width(), h = c.height();
  // Height range from a coarse pass (every 4th pixel), for the shading scale.
  double zmin = 1e9, zmax = -1e9;
  for (int y = 0; y < h; y += 4) {
    for (int x = 0; x < w; x += 4) {
      const double z = world.terrainHeight(lo.x() + x / px_per_m, hi.y() - y / px_per_m);
      zmin = std::min(zmin, z);
      zmax = std::max(zmax, z);
    }
  }
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      const double z =
          world.terrainHeight(lo.x() + (x + 0.5) / px_per_m, hi.y() - (y + 0.5) / px_per_m);
      const double f = zmax > zmin ? (z - zmin) / (zmax - zmin) : 0.5;
      const uint8_t g = static_cast<uint8_t>(225 + 25 * f);
      c.set(x, y, {g, g, static_cast<uint8_t>(g - 10)});
      const double zr =
          world.terrainHeight(lo.x() + (x + 1.5) / px_per_m, hi.y() - (y + 0.5) / px_per_m);
      const double zd =
          world.terrainHeight(lo.x() + (x + 0.5) / px_per_m, hi.y() - (y + 1.5) / px_per_m);
      if (std::floor(z) != std::floor(zr) || std::floor(z) != std::floor(zd)) {
        c.set(x, y, {190, 180, 160});
      }
    }
  }
}

// Plot border, then the understory: shrubs (light green), logs (brown).
void drawPlotAndUnderstory(const World& world, const View& v, Canvas* canvas) {
  Canvas& c = *canvas;
  const Eigen::Vector2d ps = world.plotSize();
  c.line(v.X(0), v.Y(0), v.X(ps.x()), v.Y(0), {120, 120, 120});
  c.line(v.X(ps.x()), v.Y(0), v.X(ps.x()), v.Y(ps.y()), {120, 120, 120});
  c.line(v.X(ps.x()), v.Y(ps.y()), v.X(0), v.Y(ps.y()), {120, 120, 120});
  c.line(v.X(0), v.Y(ps.y()), v.X(0), v.Y(0), {120, 120, 120});
  const size_t n_fol = world.foliage().size();
  for (size_t i = n_fol - world.numShrubs(); i < n_fol; ++i) {
    const Foliage& f = world.foliage()[i];
    c.disk(v.X(f.centre.x()), v.Y(f.centre.y()), f.radii.x() * v.px_per_m, {150, 200, 120}, 0.5);
  }
  for (const Cylinder& cy : world.cylinders()) {
    if (cy.material != Material::kLog) continue;
    const Eigen::Vector3d b = cy.a + cy.length * cy.axis;
    c.line(v.X(cy.a.x()), v.Y(cy.a.y()), v.X(b.x()), v.Y(b.y()), {140, 100, 60},
           std::max(1.0, 2 * cy.radius * v.px_per_m));
  }
}

const size_t kNumRobotColours = sizeof(kRobotColours) / sizeof(kRobotColours[0]);

// Submap extents (robust bounding boxes in S, drawn with the ground-truth pose).
void drawSubmapExtents(const std::vector<SubmapExtent>& extents, const View& v, Canvas* canvas) {
  Canvas& c = *canvas;
  for (const auto& e : extents) {
    const Rgb col = kRobotColours[e.robot_index % kNumRobotColours];
    const Eigen::Vector2d corners[4] = {{e.min_S.x(), e.min_S.y()},
                                        {e.max_S.x(), e.min_S.y()},
                                        {e.max_S.x(), e.max_S.y()},
                                        {e.min_S.x(), e.max_S.y()}};
    for (int k = 0; k < 4; ++k) {
      const Eigen::Vector3d a = e.T_W_S * Eigen::Vector3d(corners[k].x(), corners[k].y(), 0);
      const Eigen::Vector3d b =
          e.T_W_S * Eigen::Vector3d(corners[(k + 1) % 4].x(), corners[(k + 1) % 4].y(), 0);
      c.line(v.X(a.x()), v.Y(a.y()), v.X(b.x()), v.Y(b.y()), col, 1.0, 0.35);
    }
    const Eigen::Vector3d o = e.T_W_S.translation();
    c.disk(v.X(o.x()), v.Y(o.y()), 2.5, col);
  }
}

// Stems: trunks by DBH (dead ones grey), saplings as small dots.
void drawStems(const World& world, const View& v, Canvas* canvas) {
  for (const Stem& s : world.stems()) {
    const Eigen::Vector2d p = s.axisAt(1.3);
    if (s.sapling) {
      canvas->disk(v.X(p.x()), v.Y(p.y()), 0.8, {90, 150, 70});
    } else {
      canvas->disk(v.X(p.x()), v.Y(p.y()), std::max(1.5, s.r_bh * v.px_per_m * 1.5),
                   s.dead ? Rgb{130, 130, 130} : Rgb{20, 90, 30});
    }
  }
}

// Trajectories (ground truth), one colour per robot; start marked with a ring.
void drawTrajectories(const std::vector<Trajectory>& trajectories, const View& v, Canvas* canvas) {
  Canvas& c = *canvas;
  for (size_t r = 0; r < trajectories.size(); ++r) {
    const Rgb col = kRobotColours[r % kNumRobotColours];
    const auto& T = trajectories[r].T_W_B;
    for (size_t i = 10; i < T.size(); i += 10) {
      const Eigen::Vector3d a = T[i - 10].translation(), b = T[i].translation();
      c.line(v.X(a.x()), v.Y(a.y()), v.X(b.x()), v.Y(b.y()), col, 2.0);
    }
    if (!T.empty()) {
      const Eigen::Vector3d s = T.front().translation();
      c.disk(v.X(s.x()), v.Y(s.y()), 6, col, 0.6);
    }
  }
}

}  // namespace

// Layers from the bottom up: what is drawn later covers what is drawn earlier.
void writeScenePng(const std::string& path, const Simulator& sim,
                   const std::vector<SubmapExtent>& extents, double px_per_m) {
  const World& world = sim.world();
  const double margin = 4.0;
  const Eigen::Vector2d lo(-margin, -margin),
      hi = world.plotSize() + Eigen::Vector2d(margin, margin);
  const int w = static_cast<int>((hi.x() - lo.x()) * px_per_m);
  const int h = static_cast<int>((hi.y() - lo.y()) * px_per_m);
  Canvas c(w, h);
  const View view{lo, hi, px_per_m};
  drawTerrain(world, view, &c);
  drawPlotAndUnderstory(world, view, &c);
  drawSubmapExtents(extents, view, &c);
  drawStems(world, view, &c);
  drawTrajectories(sim.trajectories(), view, &c);
  c.save(path);
}

}  // namespace dtif::sim
