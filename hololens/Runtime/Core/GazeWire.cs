// Gaze wire format v1 (docs/gaze_wire_format.md): one JSON object per UDP datagram, Unity
// world values, numbers in the invariant culture. A frame with a non-finite value (the eye was
// lost mid-frame) is not encoded: the receiver would drop it, and a skipped frame is counted.
using System.Globalization;
using System.Text;

namespace FabricGuidance.Headset
{
    public struct GazeFrame
    {
        public Vec3 GazeOrigin, GazeDirection, HeadPosition;
        public Quat HeadOrientation;
        public bool EyeTrackingValid;

        public bool IsFinite
        {
            get { return GazeOrigin.IsFinite && GazeDirection.IsFinite && HeadPosition.IsFinite && HeadOrientation.IsFinite; }
        }
    }

    public static class GazeWire
    {
        public const int Version = 1;
        public const int MaxBytes = 1024;

        /// <summary>The datagram of one frame, or null when a value is NaN or infinite.</summary>
        public static byte[] Encode(uint seq, double stamp, GazeFrame f)
        {
            if (!f.IsFinite || !Vec3.Finite(stamp)) return null;
            var sb = new StringBuilder(320);
            sb.Append("{\"version\":1,\"seq\":").Append(seq.ToString(CultureInfo.InvariantCulture))
              .Append(",\"stamp\":").Append(Json.Number(stamp));
            Vector(sb, "gaze_origin", f.GazeOrigin);
            Vector(sb, "gaze_direction", f.GazeDirection);
            Vector(sb, "head_position", f.HeadPosition);
            sb.Append(",\"head_orientation\":[").Append(Json.Number(f.HeadOrientation.X)).Append(',')
              .Append(Json.Number(f.HeadOrientation.Y)).Append(',').Append(Json.Number(f.HeadOrientation.Z)).Append(',')
              .Append(Json.Number(f.HeadOrientation.W)).Append(']');
            sb.Append(",\"eye_tracking_valid\":").Append(f.EyeTrackingValid ? "true" : "false").Append('}');
            return Encoding.UTF8.GetBytes(sb.ToString());
        }

        static void Vector(StringBuilder sb, string name, Vec3 v)
        {
            sb.Append(",\"").Append(name).Append("\":[").Append(Json.Number(v.X)).Append(',')
              .Append(Json.Number(v.Y)).Append(',').Append(Json.Number(v.Z)).Append(']');
        }

        /// <summary>The confirm datagram of one press (docs/headset_wire_format.md): its press_id and
        /// the headset clock when it was pressed (the clock of the gaze stamp).</summary>
        public static byte[] EncodeConfirm(uint pressId, double stamp)
        {
            var sb = new StringBuilder(96);
            sb.Append("{\"version\":1,\"kind\":\"confirm\",\"press_id\":").Append(pressId.ToString(CultureInfo.InvariantCulture))
              .Append(",\"stamp\":").Append(Json.Number(stamp)).Append('}');
            return Encoding.UTF8.GetBytes(sb.ToString());
        }

        /// <summary>The clock_echo answering a ping: t1 exactly as the ping wrote it.</summary>
        public static byte[] EncodeEcho(uint pingSeq, string t1Text, double t2, double t3)
        {
            var sb = new StringBuilder(128);
            sb.Append("{\"version\":1,\"kind\":\"clock_echo\",\"ping_seq\":").Append(pingSeq.ToString(CultureInfo.InvariantCulture))
              .Append(",\"t1\":").Append(t1Text).Append(",\"t2\":").Append(Json.Number(t2))
              .Append(",\"t3\":").Append(Json.Number(t3)).Append('}');
            return Encoding.UTF8.GetBytes(sb.ToString());
        }
    }
}
