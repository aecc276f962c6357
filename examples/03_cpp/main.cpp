// Call the generated C solver from C++: the loop of examples/02_steer_your_loop.py, steered tick by tick.
//
//   python examples/02_steer_your_loop.py generated/example_loop     # generates the solver "loop"
//   cmake -S examples/03_cpp -B build/example_cpp -DDDPC_SOLVER_DIR=$PWD/generated/example_loop
//   cmake --build build/example_cpp && build/example_cpp/steer_loop
//
// The solver's header is plain C with extern "C" guards; all its state lives in one caller-owned workspace.
#include <array>
#include <cmath>
#include <cstdio>
#include <deque>

#include "loop_solver.h"

namespace {

constexpr double kDt = 0.01;  // s, the solver's sample time
constexpr double kPi = 3.14159265358979323846;

// Your loop (as in the Python example): z'' = kp (z_ref delayed - z) - kd z' - sag.
struct HeightLoop {
    double z = 0.0, v = 0.0;
    std::deque<double> queue = std::deque<double>(5, 0.0);
    double step(double z_ref) {
        queue.push_back(z_ref);
        const double r = queue.front();
        queue.pop_front();
        v += kDt * (25.0 * (r - z) - 7.0 * v - 2.0);
        z += kDt * v;
        return z;
    }
};

double desired(int k) {
    const double s = std::sin(2.0 * kPi * 0.1 * k * kDt);
    return 1.0 + 0.5 * s * s;
}

// Fly 12 s; returns the height RMSE after 2 s (m). steer = false flies the nominal reference.
double fly(bool steer, int* fallbacks) {
    static loop_workspace ws;  // caller-owned; no allocation inside the solver
    loop_init(&ws);
    std::array<double, LOOP_NTHETA> theta{};  // [u_ini; y_ini; y_des; u_nom], time-major
    std::array<double, LOOP_NU> u_out{};
    std::deque<double> u_past, y_past;  // the last Tini applied references and the heights they were decided on
    HeightLoop plant;
    double z = 0.0, sq = 0.0;
    int scored = 0;
    for (int k = 0; k < 1200; ++k) {
        double u = desired(k);  // the nominal reference: the path itself
        if (steer && static_cast<int>(u_past.size()) == LOOP_T_INI) {
            for (int i = 0; i < LOOP_T_INI; ++i) {
                theta[i] = u_past[i];
                theta[LOOP_T_INI + i] = y_past[i];
            }
            for (int j = 0; j < LOOP_T_F; ++j) {
                theta[2 * LOOP_T_INI + j] = desired(k + j);           // y_des over the horizon
                theta[2 * LOOP_T_INI + LOOP_T_F + j] = desired(k + j);  // u_nom over the horizon
            }
            loop_info info;
            if (loop_solve(&ws, theta.data(), u_out.data(), &info) == LOOP_SOLVED) {
                u = u_out[0];
            } else {
                ++*fallbacks;  // u_out is NaN: send the nominal reference this tick
            }
        }
        u_past.push_back(u);
        y_past.push_back(z);
        if (static_cast<int>(u_past.size()) > LOOP_T_INI) {
            u_past.pop_front();
            y_past.pop_front();
        }
        if (k >= 200) {
            sq += (z - desired(k)) * (z - desired(k));
            ++scored;
        }
        z = plant.step(u);
    }
    return std::sqrt(sq / scored);
}

}  // namespace

int main() {
    int fallbacks = 0;
    const double nominal = fly(false, &fallbacks);
    const double steered = fly(true, &fallbacks);
    std::printf("height RMSE: nominal %.1f mm, steered %.1f mm, %d fallbacks\n", 1e3 * nominal, 1e3 * steered,
                fallbacks);
    return steered < nominal ? 0 : 1;
}
