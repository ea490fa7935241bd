// What the Unity components do, without Unity, so that it is tested here: the link's life cycle
// (its display state exists from construction, so a renderer may bind to it before or after the
// link starts: Unity does not order Start between components), one gaze frame per frame with the
// head gaze, marked not valid, whenever the eyes are not tracked, and the confirm press.
// Every method is called on the owner thread (Unity's main thread): see HeadsetLink.
using System;
using System.Net;

namespace FabricGuidance.Headset
{
    /// <summary>The eye gaze of this frame in Unity world, read on the owner thread.</summary>
    public interface IEyeGazeSource
    {
        /// <summary>True with the gaze when the eyes are tracked now (and the wearer's eye calibration
        /// is valid); false when they are not: before consent, without an eye tracker, when tracking is
        /// lost. A source never returns a stale or default pose as tracked.</summary>
        bool TryGetEyeGaze(out Vec3 origin, out Vec3 direction);
    }

    public static class GazeFrames
    {
        /// <summary>Shorter eye-gaze directions are taken as no direction (OpenXR's default pose).</summary>
        public const double MinDirection = 1e-6;

        /// <summary>The frame to send: the eye gaze when tracked and usable, otherwise the head gaze
        /// (the head position and its forward axis) with EyeTrackingValid false
        /// (docs/gaze_wire_format.md: a sample is still sent when the eyes are not valid).</summary>
        public static GazeFrame Compose(Vec3 headPosition, Quat headOrientation, bool eyeTracked, Vec3 eyeOrigin, Vec3 eyeDirection)
        {
            var f = new GazeFrame { HeadPosition = headPosition, HeadOrientation = headOrientation };
            double length = eyeDirection.IsFinite
                ? Math.Sqrt(eyeDirection.X * eyeDirection.X + eyeDirection.Y * eyeDirection.Y + eyeDirection.Z * eyeDirection.Z) : 0.0;
            if (eyeTracked && eyeOrigin.IsFinite && length > MinDirection)
            {
                f.GazeOrigin = eyeOrigin;
                f.GazeDirection = eyeDirection;
                f.EyeTrackingValid = true;
                return f;
            }
            f.GazeOrigin = headPosition;
            f.GazeDirection = Forward(headOrientation);
            f.EyeTrackingValid = false;
            return f;
        }

        /// <summary>Unity's forward axis (0, 0, 1) turned by q (normalised first); NaN for a zero or
        /// non-finite q, so that the frame is skipped rather than sent with a made-up direction.</summary>
        public static Vec3 Forward(Quat q)
        {
            double n = Math.Sqrt(q.X * q.X + q.Y * q.Y + q.Z * q.Z + q.W * q.W);
            if (!q.IsFinite || !(n > 1e-9)) return new Vec3(double.NaN, double.NaN, double.NaN);
            double x = q.X / n, y = q.Y / n, z = q.Z / n, w = q.W / n;
            return new Vec3(2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y));
        }
    }

    public sealed class HeadsetSession : IDisposable
    {
        /// <summary>What the wearer should see: exists from construction, before Start.</summary>
        public readonly DisplayState Display = new DisplayState();
        /// <summary>Null until Start.</summary>
        public HeadsetLink Link { get; private set; }

        readonly IPAddress pc;
        readonly int gazePort;
        readonly IPEndPoint listen;
        readonly IHeadsetClock clock;

        /// <summary>No socket yet: Start opens them.</summary>
        public HeadsetSession(IPAddress pcAddress, int gazePort, IPEndPoint listen, IHeadsetClock clock)
        {
            pc = pcAddress;
            this.gazePort = gazePort;
            this.listen = listen;
            this.clock = clock;
        }

        public bool Started { get { return Link != null; } }

        /// <summary>Open the sockets and start receiving (once; later calls do nothing).</summary>
        public void Start()
        {
            if (Link != null) return;
            Link = new HeadsetLink(pc, gazePort, listen, clock, 0, Display);
            Link.Start();
        }

        /// <summary>Once a frame: apply what arrived, then send this frame's gaze. False when nothing
        /// was sent (not started, or a frame with NaN: counted by the link).</summary>
        public bool Update(IEyeGazeSource eyes, Vec3 headPosition, Quat headOrientation)
        {
            if (Link == null) return false;
            Link.Pump();
            Vec3 origin = default(Vec3), direction = default(Vec3);
            bool tracked = eyes != null && eyes.TryGetEyeGaze(out origin, out direction);
            return Link.SendGaze(GazeFrames.Compose(headPosition, headOrientation, tracked, origin, direction));
        }

        /// <summary>The wearer pressed confirm; false before Start (nothing to send it with).</summary>
        public bool Confirm()
        {
            if (Link == null) return false;
            Link.SendConfirm();
            return true;
        }

        public void Dispose()
        {
            if (Link != null) Link.Dispose();
        }
    }
}
