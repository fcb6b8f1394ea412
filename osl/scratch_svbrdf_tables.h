// scratch_svbrdf_tables.h -- DEFAULT constant tables of scratch_svbrdf.osl: a tiny made-up material
// (2 phi_o slices with one lobe each, or 3 phi_o nodes with 2 aim bins each) so that the .osl file compiles on its own with
// any flags.  osl/scratch_svbrdf.py replaces this include by the material's tables (same names).
// Declarations inside the shader body (OSL has no file-scope variables).

#if LOBE_TABLE
    float TB_PHI[3] = {-1.57079633, 0, 1.57079633};
    int TB_CELL[2] = {0, 1};
    float TB_AP[6] = {1, 1, 1, 1, 1, 1};
    int TB_AI[6] = {0, 1, 0, 1, 0, 1};
    float TB_TOT[3] = {0.9, 0.9, 0.9};
    float TB_CEN[6] = {0.5, 0.5, 0.5, 0.5, 0.5, 0.5};
#if KY
    float TB_Y[6] = {0.8, 0.8, 0.8, 0.8, 0.8, 0.8};
    float TB_B[6] = {1, 1, 1, 1, 1, 1};
#endif
#else
    int LM_START[3] = {0, 1, 2};
    int LM_DIST[2] = {0, 1};
    float LM_TILT[2] = {-0.3, 0.3};
    float LM_AY[2] = {0.1, 0.1};
    float LM_W[6] = {0.9, 0.9, 0.9, 0.9, 0.9, 0.9};
    float LM_GAMMA[2] = {1, 1};
#if JITTERED
    float LM_JIT[2] = {0.05, 0.05};
#endif
#if !LOSSLESS
    int L0_START[3] = {0, 1, 2};
    int L0_DIST[2] = {0, 0};
    float L0_TILT[2] = {-0.3, 0.3};
    float L0_AY[2] = {0.1, 0.1};
    float L0_W[6] = {0.8, 0.8, 0.8, 0.8, 0.8, 0.8};
    float L0_GAMMA[2] = {1, 1};
#if JITTERED
    float L0_JIT[2] = {0.05, 0.05};
#endif
#endif
#endif
#if LAYERS
    float CS_K[2] = {1, 0};  // cos Θ_k, sin Θ_k
    float XI_K[2] = {0.1, -0.2};
    float COV[3] = {3.14159265, 0.888888889, 0.444444444};  // c̄ / d²: c̄ = {0, 0.5, 1}
    float COV_DMAX = 1.5;
#endif
