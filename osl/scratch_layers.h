// scratch_layers.h -- functions of the scratch layers (Raymond et al. 2016, eq. 3 and eq. 7), shared by
// scratch_svbrdf.osl and scratch_reference.osl.  See scratch_layer_alpha.h for their use.

// Fraction of a disk footprint (radius R) covered by a scratch disk (radius a) at centre distance r:
// lens area of two circles / (pi R^2).
float disk_overlap(float a, float R, float r)
{
    if (r >= a + R) return 0.0;
    if (r <= abs(a - R)) return (a < R) ? (a * a) / (R * R) : 1.0;
    float c1 = clamp((r * r + a * a - R * R) / (2.0 * r * a), -1.0, 1.0);
    float c2 = clamp((r * r + R * R - a * a) / (2.0 * r * R), -1.0, 1.0);
    float k = (-r + a + R) * (r + a - R) * (r - a + R) * (r + a + R);
    float lens = a * a * acos(c1) + R * R * acos(c2) - 0.5 * sqrt(max(k, 0.0));
    return clamp(lens / (M_PI * R * R), 0.0, 1.0);
}

// Mean coverage c̄(d) of [F1 <= d] (precompute.scratch.layers.coverage_lookup): d² times g = c̄ / d² (g(0) = π)
// interpolated linearly on a uniform grid of [0, dmax] -- exact as d -> 0 (c̄ = π d² (1 + O(d³))), so layer
// culling at c̄ < ALPHA_CULL holds below d = sqrt(ALPHA_CULL / π) as on the SVM path.
float mean_coverage(float d, float g[], float dmax)
{
    float x = d / dmax * (arraylength(g) - 1);
    int i0 = min((int)floor(x), arraylength(g) - 2);
    return d * d * mix(g[i0], g[i0 + 1], x - i0);
}
