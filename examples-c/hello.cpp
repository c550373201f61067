// The smallest C++ use of sheaf through include/sheaf.hpp: a context owned
// by sheaf::Context, a tetrahedron, a BVH, camera rays traced as a
// std::vector, the hits drawn as text. Errors arrive as sheaf::Error.
//   make -C examples-c hello && examples-c/hello
#include "sheaf.hpp"

#include <cstdio>
#include <limits>
#include <vector>

int main() {
    const std::vector<float> vertices = {0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1};
    const std::vector<uint32_t> indices = {0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3};
    try {
        sheaf::Context ctx;
        ctx.create(static_cast<uint32_t>(indices.size() / 3));
        ctx.set_geometry(vertices, indices);
        ctx.build_bvh();
        // Orthographic rays along -z over [-0.25, 1.25]^2, 48x24.
        const int w = 48, h = 24;
        const float inf = std::numeric_limits<float>::infinity();
        std::vector<sheaf_ray> rays;
        for (int y = 0; y < h; ++y)
            for (int x = 0; x < w; ++x)
                rays.push_back(sheaf_ray{{-0.25f + 1.5f * (x + 0.5f) / w, 1.25f - 1.5f * (y + 0.5f) / h, 2.0f},
                                         0.0f,
                                         {0.0f, 0.0f, -1.0f},
                                         inf});
        std::vector<sheaf_hit> hits;
        ctx.trace(SHEAF_METHOD_BVH_SINGLE, rays, hits);
        for (int y = 0; y < h; ++y) {
            for (int x = 0; x < w; ++x) {
                const sheaf_hit &hit = hits[static_cast<size_t>(y * w + x)];
                std::putchar(hit.prim == SHEAF_INVALID_ID ? '.' : static_cast<char>('0' + hit.prim));
            }
            std::putchar('\n');
        }
    } catch (const sheaf::Error &e) {
        std::fprintf(stderr, "sheaf: %s\n", e.what());
        return 1;
    }
    return 0;
}
