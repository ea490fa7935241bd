// The Unity side of the headset link: owns the core's HeadsetLink, sends one gaze frame per
// Update from whichever IGazeSource is on the same GameObject, and applies display messages on
// the main thread (DisplayState.Pump) for DisplayRenderer. Everything else is in the core.
using System.Net;
using UnityEngine;

namespace FabricGuidance.Headset.Unity
{
    /// <summary>A gaze sample in Unity world space; the two eye-gaze components implement it.</summary>
    public interface IGazeSource
    {
        /// <summary>False when the device gives nothing this frame (the frame is not sent).</summary>
        bool TryGetGaze(out Vector3 origin, out Vector3 direction, out bool eyeTrackingValid);
    }

    /// <summary>Unity's realtimeSinceStartupAsDouble: monotonic, the clock of stamp, t2 and t3.</summary>
    sealed class UnityClock : IHeadsetClock
    {
        public double Now() { return Time.realtimeSinceStartupAsDouble; }
    }

    public sealed class HeadsetLinkBehaviour : MonoBehaviour
    {
        [Tooltip("The PC running gaze_bridge and headset_display; the only sender listened to")]
        public string pcAddress = "192.168.1.10";
        [Tooltip("gaze_bridge's UDP port (its parameter 'port')")]
        public int gazePort = 5005;
        [Tooltip("This app's downlink port (the nodes' 'display_port')")]
        public int displayPort = 5006;

        public HeadsetLink Link { get; private set; }
        IGazeSource source;

        void Start()
        {
            source = GetComponent<IGazeSource>();
            // Clock reads from the receive thread: Time.realtimeSinceStartupAsDouble is safe
            // there (unlike most of UnityEngine).
            Link = new HeadsetLink(IPAddress.Parse(pcAddress), gazePort, new IPEndPoint(IPAddress.Any, displayPort),
                                   new UnityClock());
            Link.Start();
        }

        void Update()
        {
            Link.Display.Pump();
            Vector3 origin, direction;
            bool valid;
            if (source == null || !source.TryGetGaze(out origin, out direction, out valid)) return;
            Transform head = Camera.main.transform;
            Quaternion q = head.rotation;
            Link.SendGaze(new GazeFrame
            {
                GazeOrigin = new Vec3(origin.x, origin.y, origin.z),
                GazeDirection = new Vec3(direction.x, direction.y, direction.z),
                HeadPosition = new Vec3(head.position.x, head.position.y, head.position.z),
                HeadOrientation = new Quat(q.x, q.y, q.z, q.w),
                EyeTrackingValid = valid,
            });
        }

        void OnDestroy()
        {
            if (Link != null) Link.Dispose();
        }
    }
}
