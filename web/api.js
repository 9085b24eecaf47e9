// HTTP helpers for the slamd API (docs/http-api.md): JSON requests, problem+json errors and the
// bearer token that mutating routes may need.

const kTokenKey = 'slamd.token';

/** An HTTP error; `problem` is the RFC 9457 body when the server sent one. */
export class ApiError extends Error {
  constructor(status, problem) {
    super(problem?.detail || problem?.title || `HTTP ${status}`);
    this.status = status;
    this.problem = problem ?? null;
  }

  /** The validation errors, `[{pointer, detail}]` (empty unless 422). */
  get errors() {
    return Array.isArray(this.problem?.errors) ? this.problem.errors : [];
  }
}

/** Reads a problem+json (or any JSON) error body; null when there is none. */
async function readProblem(response) {
  try {
    return await response.json();
  } catch {
    return null;
  }
}

/** GET a JSON resource; resolves to `{body, etag}`. */
export async function getJson(url) {
  const response = await fetch(url, { headers: { Accept: 'application/json' } });
  if (!response.ok) throw new ApiError(response.status, await readProblem(response));
  return { body: await response.json(), etag: response.headers.get('ETag') };
}

// ---- token -------------------------------------------------------------------------------

let tokenPrompt = null;  // set by installTokenPrompt(): () => Promise<string|null>

/** Installs the UI that asks the user for a token (resolves null when they cancel). */
export function installTokenPrompt(ask) {
  tokenPrompt = ask;
}

function storedToken() {
  try {
    return localStorage.getItem(kTokenKey);
  } catch {
    return null;  // storage disabled: the token lives only for this request
  }
}

function storeToken(token) {
  try {
    localStorage.setItem(kTokenKey, token);
  } catch {
    // Storage disabled: nothing to keep.
  }
}

/**
 * A mutating request (POST, PATCH, PUT, DELETE) with a JSON body. On 401 it asks for a token,
 * keeps it in localStorage and retries. Resolves to `{status, body, etag}`; throws ApiError.
 */
export async function mutate(method, url, options = {}) {
  const { body, contentType = 'application/json', ifMatch } = options;
  let token = storedToken();
  for (;;) {
    const headers = { Accept: 'application/json' };
    if (body !== undefined) headers['Content-Type'] = contentType;
    if (ifMatch) headers['If-Match'] = ifMatch;
    if (token) headers.Authorization = `Bearer ${token}`;
    const response = await fetch(url, {
      method,
      headers,
      body: body === undefined ? undefined : JSON.stringify(body),
    });
    if (response.status === 401 && tokenPrompt) {
      const entered = await tokenPrompt(token ? 'The token was refused.' : '');
      if (!entered) throw new ApiError(401, await readProblem(response));
      token = entered;
      storeToken(token);
      continue;
    }
    if (!response.ok) throw new ApiError(response.status, await readProblem(response));
    const text = await response.text();
    return {
      status: response.status,
      body: text ? JSON.parse(text) : null,
      etag: response.headers.get('ETag'),
    };
  }
}

/** A short human text for an error thrown by getJson/mutate or by fetch itself. */
export function describeError(error) {
  if (error instanceof ApiError) {
    const title = error.problem?.title ?? '';
    const detail = error.problem?.detail ?? '';
    if (!title && !detail) return error.message;
    return `${error.status} ${title}${title && detail ? ': ' : ''}${detail}`;
  }
  return `network error: ${error.message}`;
}
