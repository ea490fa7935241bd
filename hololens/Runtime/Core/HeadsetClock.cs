// The headset's clock: the one clock of the gaze `stamp` and of the echo's t2 and t3
// (docs/headset_wire_format.md). Monotonic: wall-clock steps (NTP, the user changing the time)
// must not look like delay.
using System.Diagnostics;

namespace FabricGuidance.Headset
{
    /// <summary>The core calls Now() on its owner thread only (HeadsetLink's threading contract), so
    /// a main-thread-only clock such as Unity's Time.realtimeSinceStartupAsDouble is fine.</summary>
    public interface IHeadsetClock
    {
        /// <summary>Seconds on the headset's monotonic clock.</summary>
        double Now();
    }

    /// <summary>Stopwatch seconds since construction, plus an offset, at a rate of 1 + driftPpm * 1e-6.
    /// The harness sets both to stand for a headset whose clock is not the PC's.</summary>
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
