// scratch_svbrdf_layer.h -- statements of scratch_svbrdf.osl computing the closure `rho` of layer k:
// ρ_k(φo, ·) of eq. 2 for the φo slice s, picked stochastically between the two slices nearest φo.
// Included inside the shader body (once per layer loop); needs k, THETA_K, t, b, n, wo, h_slice,
// h_lobe (and h_jit for JITTERED) and the lobe tables.

        float ck = cos(THETA_K[k]), sk = sin(THETA_K[k]);
        vector u = ck * t + sk * b;
        vector v = cross(n, u);
        float theta_o = asin(clamp(dot(wo, u), -1.0, 1.0));
        float phi_o = atan2(dot(wo, v), dot(wo, n));
        float x = 2.0 * abs(theta_o) / M_PI;
        // stochastic linear interpolation between the two nearest phi_o slices
        float xs = (phi_o + M_PI_2) / M_PI * MS - 0.5;
        int s = (int)floor(xs);
        if (h_slice < xs - s) s += 1;
        s = clamp(s, 0, MS - 1);
#if LOBE_TABLE
#if LOSSLESS
        closure color rho = table_lobes(TB_AP, TB_AI, TB_TOT, TB_WM, TB_WM, TB_WM, 0, s, x, h_lobe, u, v, n);
#else
        closure color rho = table_lobes(TB_AP, TB_AI, TB_TOT, TB_WM, TB_W0, TB_GAM, 1, s, x, h_lobe, u, v, n);
#endif
#elif LOBE_SUM
#if LOSSLESS
        closure color rho = lobe_set(LM_START, LM_DIST, LM_TILT, LM_AY, LM_W, LM_GAMMA JIT_ARG(LM_JIT) JIT_ARG(h_jit), s, x,
                                     u, v, n, 0, 1);
#else
        closure color rho = lobe_set(LM_START, LM_DIST, LM_TILT, LM_AY, LM_W, LM_GAMMA JIT_ARG(LM_JIT) JIT_ARG(h_jit), s, x,
                                     u, v, n, 1, 1)
                          + lobe_set(L0_START, L0_DIST, L0_TILT, L0_AY, L0_W, L0_GAMMA JIT_ARG(L0_JIT) JIT_ARG(h_jit), s, x,
                                     u, v, n, 1, 0);
#endif
#else
#if LOSSLESS
        closure color rho = pick_lobe(LM_START, LM_DIST, LM_TILT, LM_AY, LM_W, LM_GAMMA JIT_ARG(LM_JIT),
                                      LM_START, LM_DIST, LM_TILT, LM_AY, LM_W, LM_GAMMA JIT_ARG(LM_JIT), 0, s, x,
                                      h_lobe JIT_ARG(h_jit), u, v, n);
#else
        closure color rho = pick_lobe(LM_START, LM_DIST, LM_TILT, LM_AY, LM_W, LM_GAMMA JIT_ARG(LM_JIT),
                                      L0_START, L0_DIST, L0_TILT, L0_AY, L0_W, L0_GAMMA JIT_ARG(L0_JIT), 1, s, x,
                                      h_lobe JIT_ARG(h_jit), u, v, n);
#endif
#endif
