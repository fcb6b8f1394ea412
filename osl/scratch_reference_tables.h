// scratch_reference_tables.h -- DEFAULT constant tables of scratch_reference.osl: a made-up 2 x 2
// table (MT = 2) so that the .osl file compiles on its own.  osl/scratch_svbrdf.py
// (generate_reference) replaces this include by the material's tables (same names).

    float RHO_M[4] = {0.1, 0.9, 0.9, 0.1};
    float RHO_0[12] = {0.1, 0.1, 0.1, 0.8, 0.8, 0.8, 0.8, 0.8, 0.8, 0.1, 0.1, 0.1};
    float GAM[4] = {1, 1, 1, 1};
    float CDF[6] = {0, 0.1, 1, 0, 0.9, 1};
    float TOTAL[2] = {0.7, 0.7};
    float EDGE_SIN[3] = {-1, 0, 1};
#if LAYERS
    float CS_K[2] = {1, 0};  // cos Θ_k, sin Θ_k
    float XI_K[2] = {0.1, -0.2};
    float COV[3] = {3.14159265, 0.888888889, 0.444444444};  // c̄ / d²: c̄ = {0, 0.5, 1}
    float COV_DMAX = 1.5;
#endif
