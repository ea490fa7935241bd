// A strict JSON reader and the number formatting of the headset link. The core needs one of
// its own: Unity's JsonUtility maps only fixed classes and cannot tell a missing field from a
// zero, and System.Text.Json is not in Unity's profile or in Debian's mono.
using System;
using System.Collections.Generic;
using System.Globalization;
using System.Text;

namespace FabricGuidance.Headset
{
    public enum JsonKind { Object, Array, String, Number, True, False, Null }

    public sealed class JsonValue
    {
        public JsonKind Kind;
        public Dictionary<string, JsonValue> Object;
        public List<JsonValue> Array;
        public string String;
        public double Number;
        public bool IsInteger;   // written without fraction or exponent
        public string Text;      // a number as written

        public string TypeName()
        {
            switch (Kind)
            {
                case JsonKind.Object: return "an object";
                case JsonKind.Array: return "an array";
                case JsonKind.String: return "a string";
                case JsonKind.Number: return "the number " + Text;
                case JsonKind.Null: return "null";
                default: return "a boolean";
            }
        }
    }

    public sealed class JsonError : Exception
    {
        public readonly string Reason;
        public JsonError(string reason, string message) : base(message) { Reason = reason; }
    }

    public static class Json
    {
        public const int MaxDepth = 32;

        public static JsonValue Parse(string text)
        {
            int i = 0;
            JsonValue v = ReadValue(text, ref i, 0);
            SkipSpace(text, ref i);
            if (i != text.Length) throw Bad("trailing characters at " + i);
            return v;
        }

        static JsonError Bad(string what) { return new JsonError("json", "not JSON: " + what); }

        static void SkipSpace(string s, ref int i)
        {
            while (i < s.Length && (s[i] == ' ' || s[i] == '\t' || s[i] == '\n' || s[i] == '\r')) i++;
        }

        static JsonValue ReadValue(string s, ref int i, int depth)
        {
            if (depth > MaxDepth) throw Bad("nested too deeply");
            SkipSpace(s, ref i);
            if (i >= s.Length) throw Bad("ends early");
            char c = s[i];
            if (c == '{') return ReadObject(s, ref i, depth);
            if (c == '[') return ReadArray(s, ref i, depth);
            if (c == '"') return new JsonValue { Kind = JsonKind.String, String = ReadString(s, ref i) };
            if (c == '-' || (c >= '0' && c <= '9')) return ReadNumber(s, ref i);
            if (Word(s, ref i, "true")) return new JsonValue { Kind = JsonKind.True };
            if (Word(s, ref i, "false")) return new JsonValue { Kind = JsonKind.False };
            if (Word(s, ref i, "null")) return new JsonValue { Kind = JsonKind.Null };
            if (Word(s, ref i, "NaN") || Word(s, ref i, "Infinity"))
                throw new JsonError("non_finite", "NaN and Infinity are not JSON");
            throw Bad("unexpected '" + c + "' at " + i);
        }

        static bool Word(string s, ref int i, string w)
        {
            if (string.CompareOrdinal(s, i, w, 0, w.Length) != 0) return false;
            i += w.Length;
            return true;
        }

        static JsonValue ReadObject(string s, ref int i, int depth)
        {
            var obj = new Dictionary<string, JsonValue>(StringComparer.Ordinal);
            i++;
            SkipSpace(s, ref i);
            if (i < s.Length && s[i] == '}') { i++; return new JsonValue { Kind = JsonKind.Object, Object = obj }; }
            while (true)
            {
                SkipSpace(s, ref i);
                if (i >= s.Length || s[i] != '"') throw Bad("object key expected at " + i);
                string key = ReadString(s, ref i);
                SkipSpace(s, ref i);
                if (i >= s.Length || s[i] != ':') throw Bad("':' expected at " + i);
                i++;
                obj[key] = ReadValue(s, ref i, depth + 1);   // a repeated key: the last counts, as in Python
                SkipSpace(s, ref i);
                if (i < s.Length && s[i] == ',') { i++; continue; }
                if (i < s.Length && s[i] == '}') { i++; return new JsonValue { Kind = JsonKind.Object, Object = obj }; }
                throw Bad("',' or '}' expected at " + i);
            }
        }

        static JsonValue ReadArray(string s, ref int i, int depth)
        {
            var list = new List<JsonValue>();
            i++;
            SkipSpace(s, ref i);
            if (i < s.Length && s[i] == ']') { i++; return new JsonValue { Kind = JsonKind.Array, Array = list }; }
            while (true)
            {
                list.Add(ReadValue(s, ref i, depth + 1));
                SkipSpace(s, ref i);
                if (i < s.Length && s[i] == ',') { i++; continue; }
                if (i < s.Length && s[i] == ']') { i++; return new JsonValue { Kind = JsonKind.Array, Array = list }; }
                throw Bad("',' or ']' expected at " + i);
            }
        }

        static string ReadString(string s, ref int i)
        {
            var sb = new StringBuilder();
            i++;
            while (true)
            {
                if (i >= s.Length) throw Bad("unterminated string");
                char c = s[i++];
                if (c == '"') return sb.ToString();
                if (c < ' ') throw Bad("control character in a string");
                if (c != '\\') { sb.Append(c); continue; }
                if (i >= s.Length) throw Bad("unterminated escape");
                char e = s[i++];
                switch (e)
                {
                    case '"': sb.Append('"'); break;
                    case '\\': sb.Append('\\'); break;
                    case '/': sb.Append('/'); break;
                    case 'b': sb.Append('\b'); break;
                    case 'f': sb.Append('\f'); break;
                    case 'n': sb.Append('\n'); break;
                    case 'r': sb.Append('\r'); break;
                    case 't': sb.Append('\t'); break;
                    case 'u':
                        if (i + 4 > s.Length) throw Bad("short \\u escape");
                        int code;
                        if (!int.TryParse(s.Substring(i, 4), NumberStyles.AllowHexSpecifier, CultureInfo.InvariantCulture, out code))
                            throw Bad("bad \\u escape");
                        sb.Append((char)code);
                        i += 4;
                        break;
                    default: throw Bad("bad escape \\" + e);
                }
            }
        }

        static JsonValue ReadNumber(string s, ref int i)
        {
            int start = i;
            bool integer = true;
            if (s[i] == '-') i++;
            if (i >= s.Length) throw Bad("bad number");
            if (s[i] == '0') i++;
            else if (s[i] >= '1' && s[i] <= '9') while (i < s.Length && char.IsDigit(s[i]) && s[i] < 128) i++;
            else throw Bad("bad number at " + start);
            if (i < s.Length && s[i] == '.')
            {
                integer = false;
                i++;
                int digits = i;
                while (i < s.Length && s[i] >= '0' && s[i] <= '9') i++;
                if (i == digits) throw Bad("bad fraction at " + start);
            }
            if (i < s.Length && (s[i] == 'e' || s[i] == 'E'))
            {
                integer = false;
                i++;
                if (i < s.Length && (s[i] == '+' || s[i] == '-')) i++;
                int digits = i;
                while (i < s.Length && s[i] >= '0' && s[i] <= '9') i++;
                if (i == digits) throw Bad("bad exponent at " + start);
            }
            string text = s.Substring(start, i - start);
            double value;
            // An overflowing number parses as infinity on some runtimes and throws on others.
            if (!double.TryParse(text, NumberStyles.Float, CultureInfo.InvariantCulture, out value) ||
                double.IsInfinity(value) || double.IsNaN(value))
                throw new JsonError("non_finite", "the number " + Cut(text) + " is not finite as a double");
            return new JsonValue { Kind = JsonKind.Number, Number = value, IsInteger = integer, Text = text };
        }

        internal static string Cut(string text) { return text.Length > 40 ? text.Substring(0, 40) + "..." : text; }

        /// <summary>A double as JSON: invariant culture whatever the thread's culture, round trip.</summary>
        public static string Number(double value)
        {
            if (double.IsNaN(value) || double.IsInfinity(value))
                throw new ArgumentException("NaN and Infinity are not JSON numbers");
            string text = value.ToString("R", CultureInfo.InvariantCulture);
            // "R" writes integral values without a point ("3"): still a JSON number, read back equal.
            return text;
        }

        public static void AppendString(StringBuilder sb, string value)
        {
            sb.Append('"');
            foreach (char c in value)
            {
                if (c == '"') sb.Append("\\\"");
                else if (c == '\\') sb.Append("\\\\");
                else if (c < ' ') sb.Append("\\u").Append(((int)c).ToString("x4", CultureInfo.InvariantCulture));
                else sb.Append(c);
            }
            sb.Append('"');
        }
    }
}
