#include "sim/surface_mesh.h"
