// scratch_layer_alpha.h -- statements computing the coverage alpha[k] of every scratch layer
// (Raymond et al. 2016, eq. 3 over the ray footprint, layers by eq. 7); included inside the body of
// scratch_svbrdf.osl and scratch_reference.osl after scratch_frame.h.
// Needs: parameters UV, Length, Width, Density, output Alpha; tables CS_K[2 NL] (cos, sin Θ_k), XI_K[2 NL], COV (c̄ / d²),
// COV_DMAX; NL and ALPHA_CULL defined; disk_overlap (scratch_layers.h) and Cycles' node_voronoi.h.
// Declares: alpha[NL], alpha_equal (1: all equal), alpha_sum (= sum_k alpha_k = 1 - Π_k (1 - raw α_k) <= 1, also written to Alpha).
// COST_OFF (bench/scratch_cost.py only; default 0) switches stages off to time them: bit 1 = layer
// Voronoi (feature points at the cell centres, no hash), bit 2 = footprint α (binary [F1 <= d] at the point).
#ifndef COST_OFF
#define COST_OFF 0
#endif

    // UV and its footprint. Cycles' ray differentials are isotropic (no foreshortening), so the
    // footprint is stretched by 1/cos(view) along the view direction projected into the surface.
    point uvw = UV;
#ifdef FOOTPRINT_DONE  // r_uv, cbar from the early-out test of scratch_svbrdf.osl
    float r_uv = fp_r_uv;
#else
    float r_uv = max(max(length(Dx(uvw)), length(Dy(uvw))), 1e-9);
#endif
    float cos_v = max(abs(dot(wo, n)), 0.05);
    float pv_t = dot(wo, t), pv_b = dot(wo, b);
    float pv_len = hypot(pv_t, pv_b);
    if (pv_len < 1e-6) { pv_t = 1.0; pv_b = 0.0; pv_len = 1.0; }
    pv_t /= pv_len; pv_b /= pv_len;
    // Ellipse semi-axes in UV: a1 across the view (r_uv), a2 along it (r_uv / cos).
    float a1u = -pv_b * r_uv, a1v = pv_t * r_uv;
    float a2u = pv_t * r_uv / cos_v, a2v = pv_b * r_uv / cos_v;

    float d = clamp(Density, 0.0, 1.0);
#ifdef FOOTPRINT_DONE
    float cbar = fp_cbar;
#else
    float cbar = mean_coverage(d, COV, COV_DMAX);  // c̄(d), COV = c̄ / d² (precompute.scratch.layers.coverage_ratio)
#endif
    float inv_l = 1.0 / max(Length, 1e-9), inv_w = 1.0 / max(Width, 1e-9);
    float alpha[NL];
    float alpha_sum = 0.0;
    int alpha_equal = 0;  // every α_k the same (far field): the layer pick is one multiplication
    // Far field for every layer at once: a layer's footprint spread (below) is at least
    // r_uv max(1/l, 1/w) / sqrt(2) (the ellipse's orthogonal semi-axes, both >= r_uv, project onto the
    // stretched axis with squares summing to >= r_uv^2), so past 0.8 every layer's fade is 1 and
    // α_k = c̄(d) for the union below: (1 - (1 - c̄)^N) / N each (precompute.scratch.layers.far_alpha), no per-layer
    // work, and no scratch work at all when c̄(d) is culled.
#if COST_OFF & 2
    int far_all = 0;
#else
    int far_all = r_uv * max(inv_l, inv_w) >= 0.8 * M_SQRT2;
#endif
    if (far_all) {
        float a = (cbar < ALPHA_CULL) ? 0.0 : (1.0 - pow(1.0 - cbar, NL)) / NL;
        for (int k = 0; k < NL; k++)
            alpha[k] = a;
        alpha_sum = NL * a;
        alpha_equal = 1;
    } else {
    float keep = 1.0;  // Π_k (1 - α_k): the footprint fraction no layer covers
    for (int k = 0; k < NL; k++) {
        float ck = CS_K[2 * k], sk = CS_K[2 * k + 1];
        // y = diag(l, w)^-1 R(Θk) (u, v) + ξk  (eq. 7, rotation first: see scratch_svbrdf.osl)
        vector2 y = vector2((ck * uvw[0] + sk * uvw[1]) * inv_l + XI_K[2 * k],
                            (-sk * uvw[0] + ck * uvw[1]) * inv_w + XI_K[2 * k + 1]);
        // footprint semi-axes in noise space
        float e1x = (ck * a1u + sk * a1v) * inv_l, e1y = (-sk * a1u + ck * a1v) * inv_w;
        float e2x = (ck * a2u + sk * a2v) * inv_l, e2y = (-sk * a2u + ck * a2v) * inv_w;
#if COST_OFF & 2
        float spread = 0.0, fade = 0.0;  // bench: no footprint
#else
        float spread = max(hypot(e1x, e1y), hypot(e2x, e2y));
        float fade = smoothstep(0.2, 0.8, spread);  // footprint spans cells: converge to c̄(d)
#endif
        float a = cbar;
        if (fade < 1.0) {
            // α over a disk footprint of radius R = spread: the disk-disk overlap with each
            // scratch disk [F1 <= d] of the 3x3 Voronoi cells (Cycles' node_voronoi.h feature
            // points), combined as a union. Exact in the sharp limit and mean-preserving.
            float R = max(spread, 1e-6);
            vector2 cell_f = vector2(floor(y.x), floor(y.y));
#if VORONOI_INT2
            int2 cell = vec2_to_int2(cell_f);
#endif
            float miss = 1.0;
            float fx = y.x - cell_f.x, fy = y.y - cell_f.y;  // position inside the cell
            float reach = d + R;
            for (int j = -1; j <= 1; j++) {
                // distance from y to the neighbour cell's box: a cell farther than d + R cannot hold
                // a feature point whose disk meets the footprint, so it is skipped before hashing
                float by = (j < 0) ? fy : ((j > 0) ? 1.0 - fy : 0.0);
                if (by >= reach) continue;
                for (int i = -1; i <= 1; i++) {
                    float bx = (i < 0) ? fx : ((i > 0) ? 1.0 - fx : 0.0);
                    if (bx * bx + by * by >= reach * reach) continue;
#if COST_OFF & 1  // bench: no Voronoi hash (feature points at the cell centres)
                    vector2 fp = cell_f + vector2(i + 0.5, j + 0.5);
#elif VORONOI_INT2  // Blender >= 5.0 hashes integer cells (node_voronoi.h)
                    int2 off = {i, j};
                    vector2 fp = cell_f + int2_to_vec2(off) + hash_int2_to_vector2(cell + off);
#else             // Blender 4.2-4.5 hash float cell coordinates
                    vector2 off = vector2(i, j);
                    vector2 fp = cell_f + off + hash_vector2_to_vector2(cell_f + off);
#endif
#if COST_OFF & 2
                    if (distance(fp, y) <= d) miss = 0.0;
#else
                    miss *= 1.0 - disk_overlap(d, R, distance(fp, y));
#endif
                }
            }
            a = mix(1.0 - miss, cbar, fade);
        }
        alpha[k] = (a < ALPHA_CULL) ? 0.0 : a;  // layer culling (§6.1)
        alpha_sum += alpha[k];
        keep *= 1.0 - alpha[k];
    }
    // eq. 4 with independent layers (precompute.scratch.layers.union_alpha): the scratched fraction is the union
    // 1 - Π (1 - α_k), not min(Σ α_k, 1) (which reads N c̄ far away, against 1 - (1 - c̄)^N of the binary near field
    // and of the SVM twin); α_k scaled to sum to it keep the layer-pick proportions.  Binary α_k: unchanged.
    if (alpha_sum > 0.0) {
        float scale = (1.0 - keep) / alpha_sum;
        for (int k = 0; k < NL; k++)
            alpha[k] *= scale;
        alpha_sum = 1.0 - keep;
    }
    }
    Alpha = alpha_sum;
