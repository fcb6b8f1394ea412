// tabulated_brdf_tables.h -- DEFAULT constant tables of tabulated_brdf.osl: an isotropic Lambertian
// table of albedo 0.8 on the coarsest grid (RES = 2, NO = 2), so that the .osl file compiles on its
// own.  osl/tabulated_brdf.py replaces this include by a material's tables (same names).

    float F[24] = {
        0.254647911, 0.254647911, 0.254647911, 0.254647911, 0.254647911, 0.254647911, 0.254647911, 0.254647911,
        0.254647911, 0.254647911, 0.254647911, 0.254647911, 0.254647911, 0.254647911, 0.254647911, 0.254647911,
        0.254647911, 0.254647911, 0.254647911, 0.254647911, 0.254647911, 0.254647911, 0.254647911, 0.254647911
    };
    float CDF[10] = {
        0, 0.25, 0.5, 0.75, 1, 0, 0.25, 0.5, 0.75, 1
    };
    int GUIDE[8] = {
        0, 0, 1, 2, 0, 0, 1, 2
    };
