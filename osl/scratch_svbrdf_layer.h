// scratch_svbrdf_layer.h -- statements of scratch_svbrdf.osl computing the closure `rho` of layer k:
// ρ_k(φo, ·) for the φo slice s, picked stochastically between the two slices (table: nodes) around φo.
// Included inside the shader body (once per layer loop); needs k, CS_K, t, b, n, wo, h_slice,
// h_lobe (and h_jit for JITTERED) and the lobe tables.

        float ck = CS_K[2 * k], sk = CS_K[2 * k + 1];
        vector u = ck * t + sk * b;
        vector v = cross(n, u);
        float phi_o = atan2(dot(wo, v), dot(wo, n));
#if LOBE_TABLE
        // the two phi_o nodes around phi_o (cell lookup), one picked with its linear weight
        int g = clamp((int)floor((phi_o + M_PI_2) / M_PI * NG), 0, NG - 1);
        int s = TB_CELL[g];
        if (h_slice * (TB_PHI[s + 1] - TB_PHI[s]) < phi_o - TB_PHI[s]) s += 1;
#if KY
        // theta_o basis at v = 1 - sqrt(cos theta_o), linear between its NT samples
        float vt = (1.0 - sqrt(sqrt(max(1.0 - dot(wo, u) * dot(wo, u), 0.0)))) * (NT - 1);
        int it = min((int)floor(vt), NT - 2);
        float ft = vt - it;
        color yb[KY];
        for (int j = 0; j < KY; j++) {
            int q0 = 3 * (j * NT + it);
            yb[j] = mix(color(TB_B[q0], TB_B[q0 + 1], TB_B[q0 + 2]), color(TB_B[q0 + 3], TB_B[q0 + 4], TB_B[q0 + 5]), ft);
        }
        closure color rho = table_lobes(TB_AP, TB_AI, TB_TOT, TB_CEN, TB_PHI, TB_Y, yb, s, phi_o, h_lobe, u, v, n);
#else
        color yb[1] = {color(1.0)};
        closure color rho = table_lobes(TB_AP, TB_AI, TB_TOT, TB_CEN, TB_PHI, TB_PHI, yb, s, phi_o, h_lobe, u, v, n);
#endif
#else
        float theta_o = asin(clamp(dot(wo, u), -1.0, 1.0));
        float x = 2.0 * abs(theta_o) / M_PI;
        // stochastic linear interpolation between the two nearest phi_o slices
        float xs = (phi_o + M_PI_2) / M_PI * MS - 0.5;
        int s = (int)floor(xs);
        if (h_slice < xs - s) s += 1;
        s = clamp(s, 0, MS - 1);
#endif
#if LOBE_TABLE
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
