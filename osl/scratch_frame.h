// scratch_frame.h -- statements opening the body of scratch_svbrdf.osl and scratch_reference.osl
// (included inside the shader body, not at file scope).
// Needs: the shader parameter `vector Tangent`.  Declares: n, t, b (the UV frame), wo (towards the
// viewer) and the per-sample random numbers h_layer, h_lobe and (unless SLICE_FROM_PICK) h_slice.

    // Frame: n = shading normal, t = UV tangent (Tangent input, world space), b = n x t.
    // (getattribute("geom:uv"/"geom:tangent") alone does not make Cycles export the attributes:
    // the material builder links UV Map and Tangent nodes, which request them.)
    normal n = N;
    vector T = (length(Tangent) > 0.0) ? Tangent : dPdu;
    vector t = T - dot(T, n) * n;
    t = (length(t) > 1e-8) ? normalize(t) : normalize(cross(n, abs(n[0]) < 0.9 ? vector(1, 0, 0) : vector(0, 1, 0)));
    vector b = cross(n, t);
    vector wo = I;  // towards the viewer
    // Two decorrelated per-sample random numbers (OSL has no sample index; P jitters per sample).
#if SLICE_FROM_PICK
    float h_slice = 0.0;  // set from the layer pick's remainder (scratch_svbrdf.osl): one hash fewer per sample
#else
    float h_slice = hashnoise(P, dot(wo, vector(12.9898, 78.233, 37.719)));
#endif
    float h_layer = hashnoise(P, dot(wo, vector(93.989, 67.345, 24.113)) + 17.0);
    float h_lobe = hashnoise(P, dot(wo, vector(39.346, 11.135, 83.155)) + 31.0);
