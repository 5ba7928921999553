// The window's tray samples its shadow only in the rectangle around the shadow's cells and is drawn
// flat elsewhere (render/renderer.h: tray_shadow_box), so the rectangle must hold every cell the
// bilinear fetch can see nonzero.
#include "render/renderer.h"

#include <doctest/doctest.h>

#include <vector>

using namespace dvx;

TEST_CASE("tray_shadow_box: the nonzero cells grown by one, cut to the grid, empty without shadow") {
  constexpr int g = 16;
  std::vector<uint8_t> cells(g * g, 0);
  ShadowBox box = tray_shadow_box(cells.data(), g);
  CHECK(box.x0 >= box.x1);  // empty

  cells[5 * g + 7] = 3;  // (x 7, y 5)
  cells[9 * g + 4] = 1;  // (x 4, y 9)
  box = tray_shadow_box(cells.data(), g);
  CHECK(box.x0 == 3);
  CHECK(box.x1 == 9);
  CHECK(box.y0 == 4);
  CHECK(box.y1 == 11);

  // At the grid's border: cut to it.
  cells[0] = 1;
  cells[g * g - 1] = 1;
  box = tray_shadow_box(cells.data(), g);
  CHECK(box.x0 == 0);
  CHECK(box.y0 == 0);
  CHECK(box.x1 == g);
  CHECK(box.y1 == g);
}
