// The headset's clock: the one clock of the gaze `stamp` and of the echo's t2 and t3
// (docs/headset_wire_format.md). Monotonic: wall-clock steps (NTP, the user changing the time)
// must not look like delay.
using System.Diagnostics;

namespace FabricGuidance.Headset
{
    public interface IHeadsetClock
    {
        /// <summary>Seconds on the headset's monotonic clock.</summary>
        double Now();
    }

    /// <summary>Stopwatch seconds since construction, plus an offset, at a rate of 1 + driftPpm * 1e-6.
    /// In the app: offset 0, drift 0 (Unity's Time.realtimeSinceStartupAsDouble is the same kind
    /// of clock). The harness sets both to stand for a headset whose clock is not the PC's.</summary>
    public sealed class StopwatchClock : IHeadsetClock
    {
        readonly Stopwatch watch = Stopwatch.StartNew();
        readonly double offset, rate;

        public StopwatchClock(double offsetS = 0.0, double driftPpm = 0.0)
        {
            offset = offsetS;
            rate = 1.0 + driftPpm * 1e-6;
        }

        public double Now() { return offset + rate * watch.Elapsed.TotalSeconds; }
    }
}
